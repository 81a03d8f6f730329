"""Do GES's specialists master their own territories? Each specialist's policies after every round against the
e2e MLP and the step-matched e2e MLP, on designs drawn from its round-0 territory and from its final one.

    python -m experiments.ges_territories extract 9eb76ac:docs/overnight/seed0/state/ges.tar.gz ~/runs/terr/seed0
    python -m experiments.ges_territories extract d06d56e:docs/overnight/seed1/state.tar ~/runs/terr/seed1
    python -m experiments.ges_territories run docs/overnight/seed0 ~/runs/terr/seed0 ~/runs/sm/seed0 \
        [--cells obstacle-d2,obstacle-d3] [--designs 12] [--workers 2]          # resumable: rerun to go on
    python -m experiments.ges_territories table ~/runs/terr/seed0 [docs/ges_schedule/territories/seed1 ...] [--out MD]

A committed run keeps each specialist's last round only; every round's checkpoints are in its resume state in git
history (`extract` takes the main GES runs out of it). For specialist k, `designs` designs are drawn from
N(mu_k, sigma_k) clipped to the box (the territory of history.json's entry 0, what round 0 trained on, and of its
last entry, what routes the test designs) and each is scored with the run's J (policies.score_policy, the
preset's 20 episodes) by: the specialist's best policy of each round, the cell's e2e MLP, and its step-matched
e2e MLP (experiments/step_matched). Every (policy, design set) J is one cached job. Results: docs/ges_schedule/.
"""
from __future__ import annotations

import glob
import io
import json
import os
import sys
import tarfile
import zlib
from concurrent.futures import ProcessPoolExecutor

import numpy as np

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, HERE)

import ges  # noqa: E402
import ppo  # noqa: E402
from codesign import policies  # noqa: E402
import run_all  # noqa: E402
from experiments.step_matched import git_show  # noqa: E402
from runkit.files import read_json, write_json  # noqa: E402

MAIN = {f"{t}-{s}": f"{t}-{s}-K{3 if s == 'd2' else 6}-fps-lloyd" for t in run_all.TASKS for s in run_all.SPACES}


def extract(spec: str, out: str) -> None:
    """The main GES runs' folders (every round's checkpoints, history.json) from a resume state in history."""
    commit, path = spec.split(":", 1)
    with tarfile.open(fileobj=io.BytesIO(git_show(f"{commit}:{path}"))) as tar:
        for m in tar.getmembers():
            parts = m.name.split("/")
            i = parts.index("ges") if "ges" in parts else -1
            if m.isfile() and i >= 0 and len(parts) > i + 2 and parts[i + 1] in MAIN.values():
                dst = os.path.join(out, *parts[i:])
                os.makedirs(os.path.dirname(dst), exist_ok=True)
                with open(dst, "wb") as fh:
                    fh.write(tar.extractfile(m).read())
    print(f"{out}: {', '.join(sorted(os.listdir(os.path.join(out, 'ges'))))}")


def territory_designs(entry: dict, k: int, space, n: int, seed: int) -> np.ndarray:
    """n designs from specialist k's Gaussian of one history entry, clipped to the space's box."""
    rng = np.random.default_rng(seed)
    mu, sigma = np.array(entry["mu"][k]), np.array(entry["sigma"][k])
    return np.clip(mu + sigma * rng.standard_normal((n, len(mu))), space.lo, space.hi)


def J_job(key: str, ckpt: str, task: str, designs_full: list, preset_name: str, out: str) -> list:
    """One policy's J on one design set, cached in out/jobs/<key>.json (a resumable unit)."""
    path = os.path.join(out, "jobs", f"{key}.json")
    if os.path.exists(path):
        return read_json(path)["scores"]
    preset = run_all.PRESETS[preset_name]
    j = policies.score_policy(run_all.ppo.load_policy(ckpt), np.array(designs_full), task, preset, 1)
    write_json(path, {"key": key, "ckpt": ckpt, "designs": designs_full, "scores": np.asarray(j).tolist()})
    return np.asarray(j).tolist()


def jobs_of(run_folder: str, terr: str, matched: str, cells: list, n: int) -> list:
    man = read_json(os.path.join(run_folder, "results.json"))["manifest"]
    preset, seed = run_all.recorded_preset(man), int(man["seed"])
    jobs = []
    for cell in cells:
        task, sp = cell.split("-")
        space = policies.space_of(preset, task, sp)
        hist = read_json(os.path.join(terr, "ges", MAIN[cell], "history.json"))["rounds"]
        rounds = len(hist) - 1
        for k in range(len(hist[0]["mu"])):
            for which, entry in (("r0", hist[0]), ("final", hist[-1])):
                theta = territory_designs(entry, k, space, n, zlib.crc32(f"{seed}{cell}{k}{which}".encode()))
                full = space.full(theta).tolist()
                pols = {f"round{r}": ppo.best_path(os.path.join(terr, "ges", MAIN[cell], ges.ckpt_path(k, r)))
                        for r in range(rounds)}
                pols["mlp"] = os.path.join(run_folder, "policies", f"mlp-{cell}", "policy_best.pt")
                pols["matched"] = os.path.join(matched, "policies", f"mlp_matched-{cell}", "policy_best.pt")
                for name, ckpt in pols.items():
                    jobs.append(dict(key=f"{cell}-spec{k}-{which}-{name}", ckpt=ckpt, task=task, designs_full=full,
                                     preset_name=preset.name))
    return jobs


def run(run_folder: str, terr: str, matched: str, cells: list, n: int, workers: int) -> None:
    jobs = jobs_of(run_folder, terr, matched, cells, n)
    missing = [j["ckpt"] for j in jobs if not os.path.exists(j["ckpt"])]
    if missing:
        raise SystemExit(f"missing checkpoint(s): {', '.join(sorted(set(missing))[:4])}")
    todo = [j for j in jobs if not os.path.exists(os.path.join(terr, "jobs", f"{j['key']}.json"))]
    print(f"{len(jobs)} jobs, {len(todo)} to run", flush=True)
    with ProcessPoolExecutor(workers) as ex:
        futs = [ex.submit(J_job, out=terr, **j) for j in todo]
        for i, (j, f) in enumerate(zip(todo, futs)):
            print(f"[{i + 1}/{len(todo)}] {j['key']}: mean J {np.mean(f.result()):.1f}", flush=True)


def table(terrs: list) -> str:
    """Per specialist and territory: mean J of each policy, and round-last minus each e2e MLP (mean +- SE)."""
    lines = ["| seed | cell | specialist | territory | rounds' J (0, 1, ...) | e2e MLP | step-matched | "
             "last round - e2e MLP | last round - step-matched |", "|---" * 9 + "|"]
    for terr in terrs:
        seed = os.path.basename(os.path.normpath(terr)).replace("seed", "")
        rows = {}
        jobs = os.path.join(terr, "jobs") if os.path.isdir(os.path.join(terr, "jobs")) else terr   # or a docs copy
        for f in sorted(glob.glob(os.path.join(jobs, "*.json"))):
            d = read_json(f)
            cell, spec, which, pol = d["key"].rsplit("-", 3)
            rows.setdefault((cell, spec, which), {})[pol] = np.array(d["scores"])
        for (cell, spec, which), p in sorted(rows.items()):
            rnds = sorted(k for k in p if k.startswith("round"))
            if not rnds or "mlp" not in p or "matched" not in p:
                continue
            last = p[rnds[-1]]
            se = lambda d: f"{d.mean():+.1f} +- {d.std(ddof=1) / np.sqrt(len(d)):.1f}"   # noqa: E731
            lines.append(f"| {seed} | {cell} | {spec[4:]} | {which} | "
                         + ", ".join(f"{p[r].mean():.1f}" for r in rnds)
                         + f" | {p['mlp'].mean():.1f} | {p['matched'].mean():.1f} | {se(last - p['mlp'])} | "
                           f"{se(last - p['matched'])} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    from experiments import args as cli_args
    ap = cli_args.program("python -m experiments.ges_territories", __doc__, __doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("extract")
    p.add_argument("state", help="COMMIT:PATH of a resume state archive (.tar or .tar.gz)")
    p.add_argument("out")
    p = sub.add_parser("run")
    for a in ("run_folder", "terr", "matched"):
        p.add_argument(a)
    p.add_argument("--cells", default="obstacle-d2,obstacle-d3")
    p.add_argument("--designs", type=int, default=12)
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="processes (default: every core)")
    p = sub.add_parser("table")
    p.add_argument("terrs", nargs="+")
    p.add_argument("--out")
    a = ap.parse_args(argv)
    if a.cmd == "extract":
        extract(a.state, os.path.expanduser(a.out))
    elif a.cmd == "run":
        cells = a.cells.split(",")
        bad = [c for c in cells if c not in MAIN]
        if bad:
            ap.error(f"--cells: {bad} not among {sorted(MAIN)}")
        run(a.run_folder, os.path.expanduser(a.terr), os.path.expanduser(a.matched), cells, a.designs, a.workers)
    else:
        text = table([os.path.expanduser(t) for t in a.terrs])
        if a.out:
            open(a.out, "w").write(text)
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
