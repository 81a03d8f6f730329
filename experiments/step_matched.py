"""Is GES's lead specialisation or steps? run_all's step-matched e2e MLP (stage `matched`) on a committed run.

    python -m experiments.step_matched prepare docs/overnight/seed0 --state 9eb76ac:docs/overnight/seed0/state \
        --out ~/runs/sm/seed0
    python -m experiments.step_matched prepare docs/overnight/seed1 --state d06d56e:docs/overnight/seed1/state.tar \
        --out ~/runs/sm/seed1
    python -m experiments.step_matched run ~/runs/sm/seed0 [--workers 2]       # resumable: rerun to go on
    python -m experiments.ges_territories extract 9eb76ac:docs/overnight/seed0/state/ges.tar.gz ~/runs/terr/seed0
    python -m experiments.step_matched rescore ~/runs/sm/seed0 ~/runs/terr/seed0   # GES, e2e MLP on this CPU
    python -m experiments.step_matched keep ~/runs/sm/seed0 docs/overnight/seed0 docs/ges_schedule/seed0
    python -m experiments.step_matched table docs/overnight/seed0 docs/ges_schedule/seed0 [...pairs] [--out MD]

A committed run keeps its e2e MLPs without optimiser state; the ones GES warm-started from (optimiser, normaliser,
curriculum) are in git history. `prepare` copies them and the run's GES stage into a work folder, `run` trains and
scores each cell's step-matched e2e MLP there exactly as run_all's stage does, `table` sets it beside the run's
GES and e2e MLP (same designs, paired). J is bit for bit on one CPU model and code only (docs/speed): the run's own
GES and e2e MLP scores came from another machine, so `rescore` scores them again here, and `table` compares the
three on one machine's numbers. Results: docs/ges_schedule/.
"""
from __future__ import annotations

import csv
import io
import json
import os
import shutil
import subprocess
import sys
import tarfile

import numpy as np

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, HERE)

import run_all  # noqa: E402
from runkit.files import write_json  # noqa: E402
from runkit.stats import paired_comparison, verdict  # noqa: E402


def git_show(spec: str) -> bytes:
    return subprocess.run(["git", "-C", HERE, "show", spec], check=True, capture_output=True).stdout


def extract_policies(run_folder: str, state: str, out: str, wanted: list) -> None:
    """The policies `wanted` (folder names under policies/) with optimiser state from `state` (commit:folder,
    commit:file.tar, or a run's own folder), into out/policies/; each checked to be the committed one of
    `run_folder` (its scored checkpoint's weights and steps)."""
    commit, path = state.split(":", 1) if ":" in state else (None, state)   # a plain folder: a run's own
    os.makedirs(out, exist_ok=True)
    if commit is None:
        for name in wanted:
            shutil.copytree(os.path.join(path, "policies", name), os.path.join(out, "policies", name),
                            dirs_exist_ok=True)
    elif path.endswith(".tar"):
        with tarfile.open(fileobj=io.BytesIO(git_show(f"{commit}:{path}"))) as tar:
            for m in tar.getmembers():
                parts = m.name.split("/")
                if m.isfile() and len(parts) == 4 and parts[1] == "policies" and parts[2] in wanted:
                    dst = os.path.join(out, "policies", parts[2], parts[3])
                    os.makedirs(os.path.dirname(dst), exist_ok=True)
                    with open(dst, "wb") as fh:
                        fh.write(tar.extractfile(m).read())
    else:
        for name in wanted:
            for f in ("policy.pt", "policy_best.pt", "log.csv"):
                dst = os.path.join(out, "policies", name, f)
                os.makedirs(os.path.dirname(dst), exist_ok=True)
                with open(dst, "wb") as fh:
                    fh.write(git_show(f"{commit}:{path}/policies/{name}/{f}"))
    for name in wanted:   # the copied policy must be the committed one (same weights)
        a = run_all.ppo.load_checkpoint(os.path.join(out, "policies", name, "policy_best.pt"))
        b = run_all.ppo.load_checkpoint(os.path.join(run_folder, "policies", name, "policy_best.pt"))
        same = all(np.array_equal(a["policy"][k].numpy(), b["policy"][k].numpy()) for k in b["policy"])
        if not same or a["steps"] != b["steps"]:
            raise SystemExit(f"{name}: the checkpoint at {state} is not the committed one")
        print(f"{name}: {a['steps']:,} steps, optimiser state {'optimizer' in a}")


def prepare(run_folder: str, state: str, out: str) -> None:
    """The e2e MLPs with optimiser state from `state` (commit:folder or commit:file.tar) and the run's manifest and
    GES stage from its results.json, into `out`."""
    extract_policies(run_folder, state, out, [f"mlp-{t}-{s}" for t in run_all.TASKS for s in run_all.SPACES])
    res = json.load(open(os.path.join(run_folder, "results.json")))
    write_json(os.path.join(out, "stages", "ges.json"), {"stage": "ges", "result": res["stages"]["ges"]})
    write_json(os.path.join(out, "manifest.json"), res["manifest"])


def run(out: str, workers: int) -> None:
    man = json.load(open(os.path.join(out, "manifest.json")))
    r = run_all.Run(out, run_all.recorded_preset(man), int(man["seed"]), workers)
    run_all.run_stage(r, "matched")


def rescore(work: str, ges_runs: str, workers: int) -> None:
    """The e2e MLP's and GES's test score sets once more, on this machine: J is bit for bit on one CPU model only
    (docs/speed), so a run scored on another model is compared with its step-matched e2e MLP on one machine's
    numbers. `ges_runs`: a folder holding the run's main GES runs (experiments.ges_territories extract)."""
    if not os.path.exists(os.path.join(work, "ges")):
        os.symlink(os.path.abspath(os.path.join(ges_runs, "ges")), os.path.join(work, "ges"))
    man = json.load(open(os.path.join(work, "manifest.json")))
    r = run_all.Run(work, run_all.recorded_preset(man), int(man["seed"]), workers)
    jobs = [run_all.ScoreJob(work, r.preset, r.seed, t, s, m, r.main_ges(t, s) if m == "ges" else None)
            for t in run_all.TASKS for s in run_all.SPACES for m in ("mlp", "ges")]
    run_all.run_score_jobs(r, jobs, "score sets on this machine")


def keep(work: str, run_folder: str, docs: str) -> None:
    """What a later session needs of a finished work folder, into the repository: the stage's result, every score
    set and each training log under `docs`, each scored step-matched policy (optimiser dropped, as every committed
    policy) in the run's policies/ folder, where a run of today's run_all.py keeps it."""
    import shutil
    import torch
    for sub in ("scores", "logs"):
        os.makedirs(os.path.join(docs, sub), exist_ok=True)
    shutil.copy(os.path.join(work, "stages", "matched.json"), os.path.join(docs, "matched.json"))
    for f in sorted(os.listdir(os.path.join(work, "scores"))):
        shutil.copy(os.path.join(work, "scores", f), os.path.join(docs, "scores", f))
    for t in run_all.TASKS:
        for s in run_all.SPACES:
            name = f"{run_all.MATCHED}-{t}-{s}"
            shutil.copy(os.path.join(work, "policies", name, "log.csv"), os.path.join(docs, "logs", f"{name}.csv"))
            st = run_all.ppo.load_checkpoint(os.path.join(work, "policies", name, "policy_best.pt"))
            dst = os.path.join(run_folder, "policies", name, "policy_best.pt")
            os.makedirs(os.path.dirname(dst), exist_ok=True)
            torch.save({k: v for k, v in st.items() if k not in ("optimizer", "run")}, dst)
            print(f"{dst}: {st['steps']:,} steps")


def cell_rows(run_folder: str, work: str) -> list:
    """Per cell: J of GES, the e2e MLP and the step-matched e2e MLP on the run's test designs, paired; GES and the
    e2e MLP as rescored on this machine (rescore) where they are, else the run's own test scores."""
    rows = list(csv.DictReader(open(os.path.join(run_folder, "test_scores.csv"))))
    kept = os.path.join(work, "matched.json")   # a folder `keep` wrote, or the work folder itself
    matched = json.load(open(kept if os.path.exists(kept) else os.path.join(work, "stages", "matched.json")))["result"]
    man = json.load(open(os.path.join(run_folder, "results.json")))["manifest"]
    r = run_all.Run(work, run_all.recorded_preset(man), int(man["seed"]), 1)
    out = []
    for t in run_all.TASKS:
        for s in run_all.SPACES:
            here = [r.path("scores", f"{run_all.score_key(r, t, s, m)}.json") for m in ("ges", "mlp")]
            if all(os.path.exists(p) for p in here):
                g, m = (np.array(json.load(open(p))["scores"]) for p in here)
            else:
                cell = [row for row in rows if row["task"] == t and row["space"] == s]
                g, m = (np.array([float(row[k]) for row in cell]) for k in ("ges", "mlp"))
            mm = np.array(matched[f"{t}-{s}"]["scores"])
            out.append(dict(cell=f"{t} {s.upper()}", unit=run_all.UNIT[t], steps=matched[f"{t}-{s}"]["steps"],
                            rescored=all(os.path.exists(p) for p in here), ges=g.mean(), mlp=m.mean(),
                            matched=mm.mean(), vs_mlp=paired_comparison(g, m), vs_matched=paired_comparison(g, mm),
                            matched_vs_mlp=paired_comparison(mm, m)))
    return out


def fmt(c: dict) -> str:
    return f"{c['diff']:+.1f} [{c['diff_lo']:+.1f}, {c['diff_hi']:+.1f}], p={c['p']:.2g}, {verdict(c)}"


def table(pairs: list) -> str:
    lines = ["| seed | cell | steps (matched) | GES | e2e MLP | e2e MLP, step-matched | GES - e2e MLP | "
             "GES - step-matched | step-matched - e2e MLP |", "|---" * 9 + "|"]
    note = ""
    for run_folder, work in pairs:
        seed = json.load(open(os.path.join(run_folder, "results.json")))["manifest"]["seed"]
        for r in cell_rows(run_folder, work):
            note = note or ("" if r["rescored"] else " (* GES and e2e MLP: the run's own scores, maybe another CPU)")
            lines.append(f"| {seed} | {r['cell']} ({r['unit']}){'' if r['rescored'] else ' *'} | {r['steps']:,} | {r['ges']:.1f} | {r['mlp']:.1f} | "
                         f"{r['matched']:.1f} | {fmt(r['vs_mlp'])} | {fmt(r['vs_matched'])} | "
                         f"{fmt(r['matched_vs_mlp'])} |")
    return "\n".join(lines) + "\n" + note


def main(argv=None) -> int:
    from experiments import args as cli_args
    ap = cli_args.program("python -m experiments.step_matched", __doc__, __doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("prepare")
    p.add_argument("run_folder")
    p.add_argument("--state", required=True, help="COMMIT:PATH of the run's resume state (folder or .tar)")
    p.add_argument("--out", required=True)
    p = sub.add_parser("run")
    p.add_argument("out")
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="processes (default: every core)")
    p = sub.add_parser("rescore")
    p.add_argument("work")
    p.add_argument("ges_runs")
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="processes (default: every core)")
    p = sub.add_parser("keep")
    for n in ("work", "run_folder", "docs"):
        p.add_argument(n)
    p = sub.add_parser("table")
    p.add_argument("pairs", nargs="+", help="RUN_FOLDER WORK_FOLDER, repeated")
    p.add_argument("--out")
    a = ap.parse_args(argv)
    if a.cmd == "prepare":
        prepare(a.run_folder, a.state, os.path.expanduser(a.out))
    elif a.cmd == "run":
        run(os.path.expanduser(a.out), a.workers)
    elif a.cmd == "keep":
        keep(os.path.expanduser(a.work), a.run_folder, a.docs)
    elif a.cmd == "rescore":
        rescore(os.path.expanduser(a.work), os.path.expanduser(a.ges_runs), a.workers)
    else:
        if len(a.pairs) % 2:
            ap.error("table: give RUN_FOLDER WORK_FOLDER pairs")
        text = table([(a.pairs[i], os.path.expanduser(a.pairs[i + 1])) for i in range(0, len(a.pairs), 2)])
        if a.out:
            open(a.out, "w").write(text)
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
