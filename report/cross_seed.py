"""Which verdicts another seed keeps: the claims of several run_all runs (one preset, different --seed) side by
side, each claim's verdict in every run and across them, Fig. 7's K = 1 against K = 3 and the e2e MLP, and GES
against the e2e MLP inside its territories and outside.

    python -m report.cross_seed docs/overnight/seed0 docs/overnight/seed1 --out docs/overnight/CLAIMS.md

Each run is a run_all output folder (its results.json). A run's seed draws everything: its policies, GES runs and
test designs, so two seeds are two independent replications of the whole pipeline. Reads results, runs nothing.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import zlib

from report.paper import CELLS
from report.tables import claim_rows, ges_comparisons, md_table, mean_ci, territory_split, why_lines
from runkit.stats import paired_comparison, verdict

SUPPORTED, REVERSED, OPEN = "supported", "not supported", "not resolved"


def load_run(folder: str) -> dict:
    """A run's results.json (as run_all's report writes it); a one-line error if it is missing or damaged."""
    path = os.path.join(folder, "results.json")
    try:
        with open(path) as fh:
            run = json.load(fh)
    except (OSError, ValueError) as e:
        raise SystemExit(f"report.cross_seed: {path}: not a run_all results file ({type(e).__name__}: {e})")
    if not isinstance(run, dict) or not {"stages", "manifest"} <= run.keys():
        raise SystemExit(f"report.cross_seed: {path}: not a run_all results file (no stages and manifest)")
    return run


def across(verdicts: list) -> str:
    """One claim's verdicts over runs in a word: does every run agree, and on what? 'not measured' runs are left
    out (and said)."""
    v = [x for x in verdicts if x in (SUPPORTED, REVERSED, OPEN)]
    n, sup, rev = len(v), v.count(SUPPORTED), v.count(REVERSED)
    both = "both" if n == 2 else f"all {n}"
    if n == 0:
        return "not measured"
    if sup and rev:
        text = f"conflicting (supported in {sup}, reversed in {rev} of {n})"
    elif sup == n:
        text = f"holds in {both}"
    elif rev == n:
        text = f"reversed in {both}"
    elif sup:
        text = f"supported in {sup} of {n}, unresolved in the rest"
    elif rev:
        text = f"reversed in {rev} of {n}, unresolved in the rest"
    else:
        text = f"resolved in none of {n}"
    return text + ("" if n == len(verdicts) else f"; not measured in {len(verdicts) - n}")


def finding_rows(stages: dict) -> list:
    """Findings of ours the claims table does not hold, as [finding, verdict, evidence]: Fig. 7's K = 1 against
    K = 3 and against the e2e MLP (obstacle D2, paired over the run's test designs), where the run has K = 1."""
    ks, t2 = stages.get("ksens") or {}, stages.get("table2")
    if "1" not in ks:
        return []
    rows = []
    others = [("K = 3", ks.get("3", {}).get("scores"))]
    if t2:
        others.append(("the e2e MLP", t2["cells"]["obstacle-d2"]["mlp"]["scores"]))
    for name, scores in others:
        if scores is not None:
            cmp = paired_comparison(ks["1"]["scores"], scores, seed=zlib.crc32(name.encode()))
            rows.append([f"K = 1 > {name}, obstacle D2 (ours: Fig. 7)", verdict(cmp), evidence(cmp)])
    return rows


def evidence(cmp: dict) -> str:
    return f"{cmp['diff']:+.1f} [{cmp['diff_lo']:+.1f}, {cmp['diff_hi']:+.1f}], p={cmp['p']:.2g}"


def claims_table(runs: list, labels: list) -> list:
    """Every claim or finding any run measures: its verdict (and evidence) per run, and across the runs."""
    per_run = [{r[0]: r[1:] for r in claim_rows(run["stages"]) + finding_rows(run["stages"])} for run in runs]
    claims = list(dict.fromkeys(c for rows in per_run for c in rows))
    table = []
    for c in claims:
        cells = [rows.get(c, ["not measured", ""]) for rows in per_run]
        table.append([c] + [f"{v} ({e})" if e else v for v, e in cells] + [across([v for v, _ in cells])])
    return md_table(["claim"] + labels + ["across runs"], table)


def ksens_table(runs: list, labels: list) -> list:
    """Fig. 7 per run: mean J [95 % CI] of each K, the e2e MLP beside them (obstacle D2, cm)."""
    ks_all = [run["stages"].get("ksens") or {} for run in runs]
    Ks = sorted({K for ks in ks_all for K in ks}, key=lambda K: (K == "auto", int(K) if K != "auto" else 0))
    rows = [[f"K = {K}"] + [mean_ci(ks[K]["scores"]) if K in ks else "-" for ks in ks_all] for K in Ks]
    t2s = [run["stages"].get("table2") for run in runs]
    rows.append(["e2e MLP"] + [mean_ci(t2["cells"]["obstacle-d2"]["mlp"]["scores"]) if t2 else "-" for t2 in t2s])
    return md_table(["obstacle D2, cm"] + labels, rows)


def headline_counts(runs: list, labels: list) -> list:
    """Per run: in how many Table II cells GES > e2e MLP (and > e2e MoE) is supported, and reversed."""
    out = []
    for run, label in zip(runs, labels):
        t2 = run["stages"].get("table2")
        if not t2:
            continue
        parts = []
        for m, name in (("mlp", "e2e MLP"), ("moe", "e2e MoE")):
            v = [verdict(ges_comparisons(t2, *cell.split("-"))[m]) for cell in t2["cells"]]
            parts.append(f"GES > {name} supported in {v.count(SUPPORTED)} of {len(v)} cells, reversed in "
                         f"{v.count(REVERSED)}")
        out.append(f"- {label}: " + "; ".join(parts))
    return out + [""]


def split_table(runs: list, labels: list, folders: list) -> list:
    """territory_split per run, one column each: 'inside (n) / outside (n)'; then, per run, why the headline is
    not supported in each cell where it is not (report.tables.why_lines)."""
    splits = [territory_split(run["stages"], f) for run, f in zip(runs, folders)]
    if not any(splits):
        return []
    part = lambda d, n, *_: "-" if d is None else f"{d:+.1f} ({n})"   # noqa: E731
    rows = [[f"{t} {s.upper()}"] + [" / ".join(part(*p) for p in sp[f"{t}-{s}"]) if f"{t}-{s}" in sp else "-"
                                     for sp in splits] for t, s in CELLS]
    why = [line for run, lab, sp in zip(runs, labels, splits) for line in why_lines(run["stages"], sp, f"{lab}, ")]
    return (["## Where GES meets the e2e MLP: inside its territories and outside", "",
             "GES - e2e MLP, mean over the test designs inside GES's final territories (max_k f_k > e^-2, the "
             "coverage criterion of eq. 8) / outside them (n designs). Outside, the router hands a design to a "
             "specialist trained on other designs.", ""]
            + md_table(["cell"] + [f"{lab}: inside / outside" for lab in labels], rows)
            + (["Where GES > e2e MLP is not supported, why (inside: the specialists' own designs):", ""] + why + [""]
               if why else []))


def run_line(run: dict, label: str, folder: str) -> str:
    m, secs = run["manifest"], run.get("stage_seconds") or {}
    hours = sum(secs.values()) / 3600
    return (f"- {label}: `{folder}`, preset {m.get('preset')}, --seed {m.get('seed')}, commit "
            f"{str(m.get('git_commit'))[:7]}, code hash {m.get('code_hash')}, {hours:.2f} h of stages")


def report(folders: list, labels: list | None = None) -> str:
    runs = [load_run(f) for f in folders]
    labels = labels or [f"seed {run['manifest'].get('seed')}" for run in runs]
    if len(labels) != len(runs):
        raise SystemExit(f"report.cross_seed: --labels has {len(labels)} names for {len(runs)} runs")
    presets = {run["manifest"].get("preset") for run in runs}
    lines = ["# Which verdicts hold across seeds", "",
             "Each run's verdicts from its own numbers ('supported' = the claimed difference at p < 0.05, "
             "Wilcoxon signed-rank paired over that run's test designs; 'not supported' = the opposite; 'not "
             "resolved' = neither), then across the runs: a claim holds only if every run supports it.", ""]
    lines += [run_line(run, lab, f) for run, lab, f in zip(runs, labels, folders)] + [""]
    if len(presets) > 1:
        lines += [f"Note: the runs used different presets ({', '.join(sorted(map(str, presets)))}): "
                  "their budgets differ, so this is not a seed replication.", ""]
    lines += ["## The headline, per run", ""] + headline_counts(runs, labels)
    lines += ["## Claims, per run and across runs", ""] + claims_table(runs, labels)
    lines += ["## Fig. 7: K = 1 against K = 3 and the e2e MLP (obstacle D2, mean J [95 % CI], cm)", ""]
    lines += ksens_table(runs, labels)
    lines += split_table(runs, labels, folders)
    return "\n".join(lines).rstrip("\n") + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", help="run_all output folders (each with results.json)")
    ap.add_argument("--labels", help="comma-separated names of the runs (default: 'seed S' from each manifest)")
    ap.add_argument("--out", help="write the markdown here (default: print it)")
    args = ap.parse_args(argv)
    text = report(args.runs, args.labels.split(",") if args.labels else None)
    if args.out:
        with open(args.out, "w") as fh:
            fh.write(text)
    else:
        sys.stdout.write(text)


if __name__ == "__main__":
    main()
