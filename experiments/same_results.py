"""Do two run_all output folders hold the same results? The check a behaviour-preserving change must pass.

    python run_all.py --preset smoke --out ~/runs/smoke_old     # before the change (a worktree of the old commit)
    python run_all.py --preset smoke --out ~/runs/smoke_new     # after it
    python -m experiments.same_results ~/runs/smoke_old ~/runs/smoke_new

Compares, file by file, every stage's result, score set (scores and each episode's final pelvis x), TPE study,
GES state and history, test_scores.csv, and every checkpoint's weights, bit for bit. Wall times and paths differ
between any two runs and are left out (keys naming seconds, times, or the output folder). Exit 0 when equal.
"""
from __future__ import annotations

import glob
import json
import os
import sys

from experiments import args

TIMES, PATHS = ("second", "wall", "created", "reduction_pct"), ("warm_start", "run_dir", "ckpt")


def varies(key: str) -> bool:
    """A key whose value differs between any two runs: a wall time (or the cost stage's saving, a ratio of
    wall times) or a path."""
    return any(t in key for t in TIMES) or key.endswith("_s") or key in PATHS


def strip(x):
    """`x` without wall-time and path entries (they differ between any two runs)."""
    if isinstance(x, dict):
        return {k: strip(v) for k, v in x.items() if not varies(k)}
    if isinstance(x, list):
        return [strip(v) for v in x]
    return x


def files(root: str) -> list:
    pats = ("stages/*.json", "scores/*.json", "tpe/*.json", "ges/*/state.json", "ges/*/history.json",
            "test_scores.csv", "policies/*/*.pt", "ges/*/ckpt/*.ckpt")
    return sorted(os.path.relpath(f, root) for p in pats for f in glob.glob(os.path.join(root, p)))


def same_ckpt(a: str, b: str) -> bool:
    import torch
    sa, sb = (torch.load(p, map_location="cpu", weights_only=True) for p in (a, b))
    return sa["steps"] == sb["steps"] and all(torch.equal(sa["policy"][k], sb["policy"][k]) for k in sa["policy"])


def compare(a: str, b: str) -> list:
    """The differences between folders a and b, one line each ([] = the same results)."""
    fa, fb = files(a), files(b)
    diffs = [f"only in {a}: {f}" for f in sorted(set(fa) - set(fb))]
    diffs += [f"only in {b}: {f}" for f in sorted(set(fb) - set(fa))]
    for f in sorted(set(fa) & set(fb)):
        pa, pb = os.path.join(a, f), os.path.join(b, f)
        if f.endswith(".json"):
            same = strip(json.load(open(pa))) == strip(json.load(open(pb)))
        elif f.endswith(".csv"):
            same = open(pa).read() == open(pb).read()
        else:
            same = same_ckpt(pa, pb)
        if not same:
            diffs.append(f"differs: {f}")
    return diffs


def main(argv=None) -> int:
    ap = args.program("python -m experiments.same_results", __doc__)
    ap.add_argument("a", metavar="OLD", help="a run_all output folder")
    ap.add_argument("b", metavar="NEW", help="another, to compare with OLD")
    a = args.parse(ap, argv)
    diffs = compare(a.a, a.b)
    n = len(files(a.a))
    print("\n".join(diffs) if diffs else f"the same: {n} files (stages, scores, TPE, GES, checkpoints)")
    return 1 if diffs else 0


if __name__ == "__main__":
    sys.exit(main())
