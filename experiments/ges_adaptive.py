"""Study: GES with adaptive K (ges.py section 8) against fixed K on planted landscapes (docs/ges_adaptive).

For B planted sites (ges_demo.planted: B behaviours, each best in its own region) and 10 seeds per setting, in 2-D and
3-D, run GES with K = auto (starting at K_max = 8) and with fixed K in {1, 3, 6} and K = B; per run record the final K,
the rounds to 95 % coverage (or the cap of 20) and the mean score of 2,000 uniform test designs routed by eq. 10.

    python -m experiments.ges_adaptive run --out OUT [--workers 2] [--seeds 10]   # resumable: OUT/runs.jsonl
    python -m experiments.ges_adaptive report OUT --out docs/ges_adaptive   # tables.md and the K figure from OUT

Each run is seconds of one core (numpy only); the runs of one (dim, seed) share their initial states.
"""
from __future__ import annotations

import copy
import json
import os
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import ges  # noqa: E402
from experiments import args, ges_demo  # noqa: E402
from report.figures import COLORS  # noqa: E402

BS, DIMS, FIXED = (1, 2, 3, 5, 8), (2, 3), (1, 3, 6)


def settings(seeds: int) -> list:
    """(B, dim, seed, K) of every run: adaptive, the fixed Ks and K = B (once, if it is one of them)."""
    return [(B, dim, seed, K) for dim in DIMS for B in BS for seed in range(seeds)
            for K in ["auto", *dict.fromkeys([*FIXED, B])]]


_INIT = {}


def _cached_initial_state(space, config, seed, points, _initial_state=ges.initial_state):
    """ges.initial_state, computed once per (space, config, seed): it does not depend on the landscape, and its
    sigma_0 bisection is most of a short run's time; every B of a (dim, seed, K) shares it, bit for bit."""
    key = (json.dumps(space.to_dict()), repr(config), seed)
    if key not in _INIT:
        _INIT[key] = _initial_state(space, config, seed, points)
    return copy.deepcopy(_INIT[key])


def one(B: int, dim: int, seed: int, K) -> dict:
    t0 = time.time()
    ges.initial_state = _cached_initial_state   # this process's runs only
    with tempfile.TemporaryDirectory(dir="/dev/shm" if os.path.isdir("/dev/shm") else None) as d:
        res, m = ges_demo.demo_adaptive(d, K, B, dim, seed)
    rounds = res.history["rounds"]
    return {"B": B, "dim": dim, "seed": seed, "K": K, "final_K": len(res.ckpt), "rounds": res.rounds,
            "coverage": res.coverage, "mean_score": m, "K_per_round": [len(h["mu"]) for h in rounds],
            "events": [[h["round"], e["kind"]] for h in rounds for e in h.get("events", [])],
            "seconds": time.time() - t0}


def group(todo: list) -> list:
    """Runs of one (dim, seed), in one process: they share their initial states (_cached_initial_state)."""
    return [one(*t) for t in todo]


def run(out: str, seeds: int, workers: int) -> list:
    """Every run of settings(seeds) not yet in OUT/runs.jsonl, one (dim, seed) group per task, `workers` at a
    time; a rerun resumes."""
    os.makedirs(out, exist_ok=True)
    path = os.path.join(out, "runs.jsonl")
    done = load(path)
    have = {(r["B"], r["dim"], r["seed"], r["K"]) for r in done}
    todo = [s for s in settings(seeds) if s not in have]
    groups = [[t for t in todo if t[1:3] == g] for g in dict.fromkeys(t[1:3] for t in todo)]
    weight = {2: 1.0, 3: 6.0}   # a 3-D run takes ~6x a 2-D one (measured): the ETA counts runs so weighted
    total, t0, n, w = sum(weight[t[1]] for t in todo), time.time(), 0, 0.0
    with ProcessPoolExecutor(workers) as ex, open(path, "a") as fh:
        for rs in ex.map(group, groups):
            for r in rs:
                fh.write(json.dumps(r) + "\n")
            fh.flush()
            done += rs
            n, w = n + len(rs), w + sum(weight[r["dim"]] for r in rs)
            el = time.time() - t0
            print(f"[ges_adaptive] {n}/{len(todo)} runs, {el:.0f} s, eta {el / w * (total - w):.0f} s", flush=True)
    return done


def load(path: str) -> list:
    if not os.path.exists(path):
        return []
    with open(path) as fh:
        return [json.loads(line) for line in fh if line.strip()]


def pick(runs, **kw) -> list:
    return [r for r in runs if all(r[k] == v for k, v in kw.items())]


def trained(runs: list) -> float:
    """Mean specialist-rounds a run trained (the K of every round it trained, summed): its training cost."""
    return float(np.mean([sum(r["K_per_round"][:-1]) for r in runs]))


def tables(runs: list) -> tuple[list, dict]:
    """Markdown rows per (dim, B) and each goal's verdict."""
    lines = ["| d | B | auto: final K (median, range) | K within B +-1 | rounds to 95 %: auto / K = B (median) | "
             "mean score: auto / K=1 / K=3 / K=6 / K=B | auto / best fixed of 1, 3, 6 | "
             "specialist-rounds trained: auto / K = B (mean) |",
             "|---|---|---|---|---|---|---|---|"]
    goals = {"K": [], "score": [], "rounds": []}
    for dim in DIMS:
        for B in BS:
            auto = pick(runs, B=B, dim=dim, K="auto")
            if not auto:
                continue
            fk = np.array([r["final_K"] for r in auto])
            near = float(np.mean(np.abs(fk - B) <= 1))
            mean = {K: np.mean([r["mean_score"] for r in pick(runs, B=B, dim=dim, K=K)]) for K in [*FIXED, B]}
            m_auto = np.mean([r["mean_score"] for r in auto])
            best = max(mean[K] for K in FIXED)
            r_auto = np.median([r["rounds"] for r in auto])
            r_B = np.median([r["rounds"] for r in pick(runs, B=B, dim=dim, K=B)])
            if B in (1, 2, 3, 5):
                goals["K"].append((dim, B, near))
            goals["score"].append((dim, B, m_auto / best))
            goals["rounds"].append((dim, B, r_auto, r_B))
            lines.append(f"| {dim} | {B} | {np.median(fk):.0f} ({fk.min()}-{fk.max()}) | {near:.0%} | "
                         f"{r_auto:.1f} / {r_B:.1f} | {m_auto:.3f} / " + " / ".join(f"{mean[K]:.3f}" for K in
                                                                                   [*FIXED, B]) +
                         f" | {m_auto / best:.3f} | {trained(auto):.0f} / "
                         f"{trained(pick(runs, B=B, dim=dim, K=B)):.0f} |")
    return lines, goals


def figure(runs: list, path: str) -> str:
    """K over rounds of the adaptive runs: median and range over seeds per B, one panel per dimension."""
    from matplotlib.figure import Figure
    fig = Figure(figsize=(9, 3.4), layout="constrained")
    axes = fig.subplots(1, len(DIMS), sharey=True)
    for ax, dim in zip(axes, DIMS):
        for c, B in enumerate(BS):
            ks = [r["K_per_round"] for r in pick(runs, B=B, dim=dim, K="auto")]
            if not ks:
                continue
            n = max(map(len, ks))
            pad = np.array([k + [k[-1]] * (n - len(k)) for k in ks], dtype=float)   # a finished run keeps its K
            t = np.arange(n)
            col = COLORS[c % len(COLORS)]
            ax.plot(t, np.median(pad, 0), "-", color=col, lw=1.8, label=f"B = {B}")
            ax.fill_between(t, pad.min(0), pad.max(0), color=col, alpha=0.15)
            ax.axhline(B, color=col, ls=":", lw=0.8)
        ax.set(xlabel="round", title=f"{dim}-D planted landscapes", yticks=range(1, 9))
    axes[0].set_ylabel("K (adaptive, started at K_max = 8)")
    fig.suptitle("K over rounds: median (line) and range (band) of 10 seeds per B; dotted: K = B", fontsize=10)
    axes[0].legend(fontsize=8, loc="center right")
    fig.savefig(path, dpi=110)
    return path


def main(argv=None) -> int:
    ap = args.program("python -m experiments.ges_adaptive", __doc__)
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = args.command(sub, "run", "run the study (resumes OUT/runs.jsonl) and print its tables", __doc__)
    r.add_argument("--out", required=True, help="the study's folder: runs.jsonl")
    r.add_argument("--seeds", type=int, default=10)
    args.add_workers(r)
    t = args.command(sub, "report", "write tables.md and k_over_rounds.png from a run's folder", __doc__)
    t.add_argument("runs", metavar="OUT", help="the folder `run` wrote")
    t.add_argument("--out", required=True, metavar="DIR", help="where tables.md and k_over_rounds.png go")
    a = args.parse(ap, argv)
    runs = load(os.path.join(a.runs, "runs.jsonl")) if a.cmd == "report" else run(a.out, a.seeds, a.workers)
    lines, goals = tables(runs)
    print("\n".join(lines))
    for g, v in goals.items():
        print(g, v)
    if a.cmd == "report":
        os.makedirs(a.out, exist_ok=True)
        with open(os.path.join(a.out, "tables.md"), "w") as fh:
            fh.write("\n".join(lines) + "\n")
        print(figure(runs, os.path.join(a.out, "k_over_rounds.png")))
    return 0


if __name__ == "__main__":
    sys.exit(main())
