"""experiments/authors_setup.py -- the D2 cells in the authors' setup beside Table I's, seed by seed.

The authors' GES experiments ran each task on its own box and D2 robot (docs/facts.md sec. 14), which run_all.py
runs with `--set setup=authors`; Table I's setup is the paper's text and our committed runs. This tool puts a
run of each setup side by side, per seed and D2 cell: every method's mean J [95 % CI], GES minus each other
method paired over the run's own test designs, and the paper's numbers. Obstacle cells of Table I's runs are read
from the stay-band study's rescoring (docs/stay_band: those runs were scored by the facts' J; `--rule` picks
which), so that both setups are read with one rule. [ours]

    python run_all.py --preset overnight --set setup=authors --set cells=obstacle-d2,ramp-d2 --seed S \\
        --only table1,baselines,ges,matched,table2 --out ~/runs/authors/seedS
    python -m experiments.authors_setup --table docs/overnight/seed0 docs/overnight/seed1 \\
        --authors ~/runs/authors/seed0 ~/runs/authors/seed1 --rescore docs/stay_band/data/rescore.json
    python -m experiments.authors_setup --table docs/overnight/seed0 --boxes docs/authors_setup/boxes.png

Results: docs/authors_setup/README.md.
"""
from __future__ import annotations

import json
import os
import sys
import zlib

import numpy as np

from experiments import args
from report.paper import PAPER_TABLE2
from report.tables import mean_ci, md_table
from runkit.stats import paired_comparison, verdict

CELLS = ("obstacle-d2", "ramp-d2")
METHODS = ("ges", "mlp", "moe", "mlp_matched")
NAMES = {"ges": "GES", "mlp": "e2e MLP", "moe": "e2e MoE", "mlp_matched": "e2e MLP, step-matched"}


def load_run(run: str) -> dict:
    """A run folder's results.json, with its folder under "run"."""
    return {**json.load(open(os.path.join(run, "results.json"))), "run": run}


def setup_of(doc: dict) -> str:
    return doc["manifest"]["budgets"].get("setup", "table")


def run_scores(doc: dict, cell: str, rescore: dict | None, rule: str) -> dict:
    """{method: scores over the run's test designs} of one cell; a run scored by the facts' J has its obstacle
    cells from `rescore` (experiments.stay_band rescore: keys 'RUN|d2|METHOD|RULE') under `rule`."""
    run, stages, manifest = doc["run"], doc["stages"], doc["manifest"]
    scored = "strict" if manifest["budgets"].get("score_strict") else "facts"
    task, sp = cell.split("-")
    if task == "obstacle" and scored != rule:
        if rescore is None:
            raise args.BadArg(f"{run} scored its obstacle J by the {scored} rule, not {rule}: give --rescore (stay_band's JSON)")
        keys = {m: f"{os.path.relpath(run)}|{sp}|{m}|{rule}" for m in METHODS}
        missing = [k for k in keys.values() if k not in rescore and not k.startswith("docs/quick")]
        if missing:
            raise args.BadArg(f"--rescore has no {missing[0]!r}: run experiments.stay_band rescore {run} first")
        return {m: np.array(rescore[k]["J"]) for m, k in keys.items() if k in rescore}
    c = stages["table2"]["cells"][cell]
    out = {m: np.array(c[m]["scores"]) for m in ("ges", "mlp", "moe")}
    if stages.get("matched") and cell in stages["matched"]:
        out["mlp_matched"] = np.array(stages["matched"][cell]["scores"])
    return out


def rows_of(label: str, doc: dict, cell: str, rescore, rule: str) -> list:
    s = run_scores(doc, cell, rescore, rule)
    cmps = []
    for m in ("mlp", "moe", "mlp_matched"):
        if m not in s:
            cmps.append("-")
            continue
        c = paired_comparison(s["ges"], s[m], seed=zlib.crc32(f"{cell}{m}".encode()))
        cmps.append(f"{c['diff']:+.1f} [{c['diff_lo']:+.1f}, {c['diff_hi']:+.1f}], p = {c['p']:.2g}, "
                    + {"supported": "yes", "not supported": "no", "not resolved": "open"}[verdict(c)])
    means = [mean_ci(s[m]) if m in s else "-" for m in METHODS]
    return [[label, f"{len(s['ges'])}"] + means + cmps]


def cmd_boxes(runs: list, out: str) -> None:
    """Fig.: each task's D2 box in both setups, in (GCR, SPCF), with the Table I runs' test designs; prints the
    share of those designs inside the authors' box."""
    import csv
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import ballu
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.8))
    for ax, task in zip(axes, ("obstacle", "ramp")):
        for setup, colour in (("table", "tab:blue"), ("authors", "tab:red")):
            sp = ballu.d2(task, setup)
            (g0, s0), (g1, s1) = sp.lows, sp.highs
            legs = "{:.3g} / {:.3g} m".format(sp.fixed["l_f"], sp.fixed["l_t"])
            ax.add_patch(plt.Rectangle((g0, s0), g1 - g0, s1 - s0, fill=False, ec=colour, lw=2,
                                       label=("Table I's box" if setup == "table" else "the authors' box") + f", legs {legs}"))
        pts = np.array([[float(r["gcr"]), float(r["spcf"])] for run in runs
                        for r in csv.DictReader(open(os.path.join(run, "test_scores.csv")))
                        if r["task"] == task and r["space"] == "d2"])
        share = np.mean(ballu.d2(task, "authors").contains(pts))
        ax.scatter(pts[:, 0], pts[:, 1], s=8, c="k", label=f"Table I runs' test designs ({100 * share:.0f} % in theirs)")
        print(f"{task} D2: {len(pts)} test designs of {', '.join(runs)}, {100 * share:.0f} % inside the authors' box")
        ax.set(title=f"{task} D2", xlabel="GCR", ylabel="SPCF", xlim=(0.70, 0.92), ylim=(0, 0.105))
        ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


def cmd_table(a) -> None:
    if a.boxes:
        return cmd_boxes(a.table, a.boxes)
    rescore = json.load(open(a.rescore)) if a.rescore else None
    if len(a.table) != len(a.authors):
        raise args.BadArg(f"--table and --authors pair run by run (seed by seed): {len(a.table)} and "
                          f"{len(a.authors)} folders given")
    table, authors = [load_run(r) for r in a.table], [load_run(r) for r in a.authors]
    for doc, want in [(d, "table") for d in table] + [(d, "authors") for d in authors]:
        if setup_of(doc) != want:
            raise args.BadArg(f"{doc['run']} ran setup={setup_of(doc)!r}, not {want!r}")
    head = ["seed: setup", "designs"] + [NAMES[m] for m in METHODS] + [f"GES - {NAMES[m]}"
                                                                       for m in ("mlp", "moe", "mlp_matched")]
    for cell in CELLS:
        task, sp = cell.split("-")
        paper = PAPER_TABLE2[(task, sp)]
        rows = []
        for t_doc, a_doc in zip(table, authors):
            seed = a_doc["manifest"]["seed"]
            rows += rows_of(f"{seed}: Table I", t_doc, cell, rescore, a.rule)
            rows += rows_of(f"{seed}: authors'", a_doc, cell, rescore, a.rule)
        rows.append(["paper", "1000", f"{paper['ges']}", f"{paper['mlp']}", f"{paper['moe']}", "-",
                     f"{paper['ges'] - paper['mlp']:+.1f}", f"{paper['ges'] - paper['moe']:+.1f}", "-"])
        unit = "cm, obstacle J by the " + a.rule + " rule" if task == "obstacle" else "deg"
        print(f"**{task} D2** ({unit}): mean [95 % CI] over each run's test designs; GES - the other method "
              "[95 % paired-bootstrap CI], Wilcoxon p, 'GES > it' yes / no / open\n")
        print("\n".join(md_table(head, rows)) + "\n")


def main(argv=None) -> int:
    p = args.program("experiments.authors_setup", __doc__)
    p.add_argument("--table", nargs="+", required=True, help="runs in Table I's setup (the committed ones)")
    p.add_argument("--authors", nargs="+", default=[], help="runs with --set setup=authors, the same seeds")
    p.add_argument("--boxes", help="instead of the table: a PNG of both setups' D2 boxes and --table's test designs")
    p.add_argument("--rescore", help="experiments.stay_band rescore's JSON, for Table I's obstacle cells")
    p.add_argument("--rule", default="strict", choices=("facts", "strict"), help="the obstacle J's rule")
    a = args.parse(p, argv)
    try:
        cmd_table(a)
    except (args.BadArg, FileNotFoundError, KeyError) as e:   # a folder that is not a run, or lacks a cell
        p.error(f"{type(e).__name__}: {e}" if not isinstance(e, args.BadArg) else str(e))
    return 0


if __name__ == "__main__":
    sys.exit(main())
