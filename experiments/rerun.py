"""Rerun a committed run from GES on: its baseline policies reused, every stage after them run by today's code.

    python -m experiments.rerun docs/overnight/seed0 --state 9eb76ac:docs/overnight/seed0/state \
        --out ~/runs/overnight-s0 [--set FIELD=VALUE ...]
    python run_all.py --preset overnight --seed 0 --out ~/runs/overnight-s0 [--set ...] --stop-by 06:30   # then this

A change of GES's schedule (docs/ges_schedule) leaves the baselines as they were: the baseline design's policies,
the e2e MLPs and MoEs train before GES and do not depend on it. So a rerun starts a new folder with today's code
(run_all.py --only table1: its manifest, the preset, seed and --set overrides), copies the committed run's
policies into it with their optimiser state (in git history: the committed policies drop it; GES warm-starts
from the e2e MLPs' full checkpoints), each checked to be the committed one, and leaves the rest to run_all.py:
its baselines stage finds every policy at its steps and keeps it (codesign.policies.train_policy), its log's
seconds stay the original training's (the cost stage counts them), and GES, the step-matched e2e MLP, the tables
and figures run as in any run. Results: the run's RUN.md says which stages it reused.
"""
from __future__ import annotations

import json
import os
import sys

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, HERE)

import run_all  # noqa: E402
from experiments import args as cli_args  # noqa: E402
from experiments.step_matched import extract_policies  # noqa: E402
from runkit.cli import override  # noqa: E402


def prepare(run_folder: str, state: str, out: str, sets: list) -> list:
    """A new run folder at `out` holding the committed run's baseline policies; returns the run_all.py arguments
    that go on from there."""
    man = json.load(open(os.path.join(run_folder, "results.json")))["manifest"]
    argv = ["--preset", man["preset"], "--seed", str(man["seed"]), "--out", out]
    argv += [x for s in sets for x in ("--set", s)]
    if os.path.exists(out):
        raise cli_args.BadArg(f"--out {out} exists: a rerun starts a new folder")
    if run_all.main(argv + ["--only", "table1"]) != 0:
        raise cli_args.BadArg(f"run_all.py {' '.join(argv)} refused: see its message above")
    r = run_all.Run(out, override(run_all.PRESETS[man["preset"]], sets)[0], int(man["seed"]), 1)
    extract_policies(run_folder, state, out, [name for name, *_ in run_all.baseline_jobs(r)])
    return argv


def main(argv=None) -> int:
    ap = cli_args.program("python -m experiments.rerun", __doc__)
    ap.add_argument("run_folder", help="the committed run (its results.json and policies/)")
    ap.add_argument("--state", required=True, help="COMMIT:PATH of the run's resume state (folder or .tar)")
    ap.add_argument("--out", required=True, help="the new run folder (must not exist)")
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE", help="run_all's preset overrides")
    a = cli_args.parse(ap, argv)
    try:
        go_on = prepare(a.run_folder, a.state, os.path.expanduser(a.out), a.set)
    except cli_args.BadInput as e:
        print(f"rerun: error: {e}", file=sys.stderr)
        return 2
    print("now: python run_all.py " + " ".join(go_on) + " [--stop-by HH:MM]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
