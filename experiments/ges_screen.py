"""Which GES schedule makes specialists beat the step-matched e2e MLP? A screen of schedule levers on a committed run.

    python -m experiments.ges_screen prepare docs/overnight/seed0 --state 9eb76ac:docs/overnight/seed0/state \
        --ges-runs ~/runs/terr/seed0 --out ~/runs/screen/seed0
    python -m experiments.ges_screen run ~/runs/screen/seed0 --lever final --set ges_final_train=true --reuse-round0
    python -m experiments.ges_screen run ~/runs/screen/seed0 --lever long --set ges_round_steps=540000 --reuse-round0 --matched
    python -m experiments.ges_screen pick ~/runs/screen/seed0 --lever final     # --lever run: the run's own GES
    python -m experiments.ges_screen split ~/runs/screen/seed1 --lever final   # per specialist, routed test designs
    python -m experiments.ges_screen table ~/runs/screen/seed0 ~/runs/screen/seed1 --out docs/ges_schedule/screen.md

One fixed protocol for every lever [ours, issue 95]: the run's own e2e MLPs (with optimiser state, from its resume
state in git history) as GES's warm start, the run's preset with the lever's `--set` overrides (run_all's
vocabulary), obstacle D2 and D3 (`--cells`), the run's seed, and the run's own test designs, paired. `prepare`
scores the e2e MLP, the step-matched e2e MLP (committed in the run's policies/) and, with `--ges-runs` (a folder
of experiments.ges_territories extract), the run's own GES on this machine: J is bit for bit on one CPU model
only (docs/speed), so every number a table compares comes from the machine that ran the screen. `run` is
resumable (rerun to go on); `table` prints each lever's GES against the three, per cell. Results:
docs/ges_schedule/.
"""
from __future__ import annotations

import json
import os
import shutil
import sys
from dataclasses import replace

import numpy as np

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, HERE)

import ges  # noqa: E402
from codesign import policies  # noqa: E402
import run_all  # noqa: E402
from experiments import args as cli_args  # noqa: E402
from experiments.step_matched import fmt, prepare as copy_warm_starts  # noqa: E402
from runkit.cli import override  # noqa: E402
from runkit.files import read_json, write_json  # noqa: E402
from runkit.progress import say  # noqa: E402
from runkit.stats import paired_comparison  # noqa: E402

CELLS = ("obstacle-d2", "obstacle-d3")   # the screen cells: the obstacle, where GES's lead is open
BASES = ("mlp", run_all.MATCHED, "ges")   # what every lever is compared with, scored at prepare
RUN = "run"   # the lever name of the run's own GES: `pick --lever run` picks its specialists' rounds
SAME = "same"   # the lever that reruns the run's schedule here, from its round 0: a lever's own effect is against it


def base_run(work: str, workers: int = 1, preset=None) -> run_all.Run:
    man = read_json(os.path.join(work, "manifest.json"))
    return run_all.Run(work, preset or run_all.recorded_preset(man), int(man["seed"]), workers)


def prepare(run_folder: str, state: str, out: str, ges_runs: str | None, cells: tuple, workers: int) -> None:
    """The run's e2e MLPs with optimiser state (experiments.step_matched.prepare), its committed step-matched
    policies, and the comparison's score sets on this machine: e2e MLP, step-matched, the run's own GES."""
    copy_warm_starts(run_folder, state, out)
    os.remove(os.path.join(out, "stages", "ges.json"))   # each lever runs its own GES stage
    for c in cells:
        src = os.path.join(run_folder, "policies", f"{run_all.MATCHED}-{c}", "policy_best.pt")
        dst = os.path.join(out, "policies", f"{run_all.MATCHED}-{c}", "policy_best.pt")
        os.makedirs(os.path.dirname(dst), exist_ok=True)
        shutil.copy(src, dst)
    if ges_runs and not os.path.lexists(os.path.join(out, "ges")):   # a rerun of prepare goes on
        os.symlink(os.path.abspath(os.path.join(ges_runs, "ges")), os.path.join(out, "ges"))
    r = base_run(out, workers)
    jobs = [run_all.ScoreJob(out, r.preset, r.seed, *c.split("-"), m, r.main_ges(*c.split("-")) if m == "ges" else None)
            for c in cells for m in BASES if m != "ges" or ges_runs]
    run_all.run_score_jobs(r, jobs, "the screen's comparison, on this machine")
    write_json(os.path.join(out, "screen.json"), {"cells": list(cells), "levers": {}})


# the preset fields a lever may change and still start from the run's own round 0 (--reuse-round0): they act
# after round 0's training, which depends on GES's initialisation, its seed and round 0's steps alone
AFTER_ROUND0 = {"probe_tiebreak", "ges_probes", "ges_init_designs", "ges_final_train", "ges_round_steps",
                "ges_max_rounds", "ges_target_coverage"}


def reuse_round0(work: str, folder: str, r) -> None:
    """The run's round-0 specialists (checkpoint with optimiser, best window, log) copied into the lever's GES
    runs: GES's train_fn keeps a checkpoint that has its steps (policies.train_policy), so round 0 is the run's
    own and the lever trains from round 1 on, a quarter of an overnight specialist's steps."""
    for t, s in r.cells():
        name = r.main_ges(t, s)
        src, dst = os.path.join(work, "ges", name, ges.CKPT_DIR), os.path.join(folder, "ges", name, ges.CKPT_DIR)
        os.makedirs(dst, exist_ok=True)
        for f in sorted(os.listdir(src)):
            if "_round00" in f and not os.path.exists(os.path.join(dst, f)):
                shutil.copy(os.path.join(src, f), os.path.join(dst, f))


def run(work: str, lever: str, sets: list, workers: int, round0: bool = False, matched: bool = False) -> None:
    """One lever: GES on the screen's cells with the run's preset and `sets` overrides, warm-started from the
    run's e2e MLPs, then its test scores. In <work>/<lever>/, resumable. `round0`: from the run's own round 0
    (reuse_round0), for levers that change only AFTER_ROUND0 fields. `matched`: also the step-matched e2e MLP at
    this lever's steps per specialist (run_all's stage), for levers that change them; the table then compares
    the lever's GES with it instead of the run's."""
    if lever == RUN:
        raise cli_args.BadArg(f"--lever {RUN}: the run's own GES (pick's); name this lever otherwise")
    screen, base = read_json(os.path.join(work, "screen.json")), base_run(work)
    preset = lever_preset(base.preset, sets, screen["cells"])
    old, reused = screen["levers"].get(lever), screen.setdefault("round0_reused", [])
    if old is not None and (old != list(sets) or (lever in reused) != round0):
        raise cli_args.BadArg(f"lever {lever!r} ran with --set {old}{' --reuse-round0' * (lever in reused)}, not "
                              f"{sets}{' --reuse-round0' * round0}: name another lever")
    if round0:
        changed = {x.partition("=")[0] for x in sets} - AFTER_ROUND0
        if changed or not os.path.isdir(os.path.join(work, "ges")):
            raise cli_args.BadArg(f"--reuse-round0: needs prepare's --ges-runs and levers of "
                                  f"{', '.join(sorted(AFTER_ROUND0))} alone ({', '.join(sorted(changed))} change round 0)")
    screen["levers"][lever] = list(sets)
    screen["round0_reused"] = sorted(set(reused) | {lever} if round0 else set(reused))
    write_json(os.path.join(work, "screen.json"), screen)
    folder = os.path.join(work, lever)
    os.makedirs(folder, exist_ok=True)
    link_policies(work, folder, matched)
    shutil.copy(os.path.join(work, "manifest.json"), os.path.join(folder, "manifest.json"))
    r = replace(base, out=folder, preset=preset, workers=workers)
    if round0:
        reuse_round0(work, folder, r)
    run_all.run_stage(r, "ges")
    jobs = [run_all.ScoreJob(folder, preset, r.seed, t, s, "ges", r.main_ges(t, s)) for t, s in r.cells()]
    run_all.run_score_jobs(r, jobs, f"lever {lever}: GES on the test designs")
    if matched:
        run_all.run_stage(r, "matched")


def link_policies(work: str, folder: str, matched: bool) -> None:
    """The lever's policies/: the run's, linked (one link per policy, so the lever's own step-matched e2e MLPs
    train beside them and never over the run's); a folder linked whole by older code is kept unless `matched`."""
    mine = os.path.join(folder, "policies")
    if os.path.islink(mine):
        if matched:
            raise cli_args.BadArg(f"{mine} links the run's policies whole: --matched needs a lever of its own")
        return
    os.makedirs(mine, exist_ok=True)
    for name in sorted(os.listdir(os.path.join(work, "policies"))):
        if not name.startswith(run_all.MATCHED) and not os.path.lexists(os.path.join(mine, name)):
            os.symlink(os.path.abspath(os.path.join(work, "policies", name)), os.path.join(mine, name))


def pick(work: str, lever: str, n: int = 12, workers: int = 1) -> dict:
    """The lever "pick" [ours, item 3], after a lever's GES: each specialist's scored policy chosen across its
    rounds by J on `n` designs of its final territory (a later round on a grown territory may serve its designs
    worse: docs/ges_schedule, territories), then the test designs routed (eq. 10) and scored with the chosen
    policies: score set test-<cell>-ges-picked. Returns cell -> each specialist's chosen round."""
    r, chosen = lever_run(work, lever, workers), {}
    for t, s in r.cells():
        res, space = policies.load_ges(r.path("ges", r.main_ges(t, s))), policies.space_of(r.preset, t, s)
        J, best, ckpt = policies.ScoreSpecialist(t, space, r.preset, workers), [], []
        for k, i in enumerate(res.ids):   # every round's checkpoint of specialist i (a final training's too)
            rounds = [c for c in (os.path.join(res.run_dir, ges.ckpt_path(i, x))
                                  for x in range(res.rounds + 1)) if os.path.exists(c)]
            sampler = ges.GaussianSampler(res.mu_unit[k], res.sigma_unit[k], res.space)
            designs = sampler(np.random.default_rng(policies.derive_seed(r.seed, "pick", t, s, k)), n)
            js = [float(np.mean(J(k, c, designs))) for c in rounds]
            best.append(int(np.argmax(js)))
            ckpt.append(rounds[best[-1]])
            say(f"pick {lever} {t}-{s} specialist {i}: rounds' J {', '.join(f'{j:.1f}' for j in js)} -> round {best[-1]}")
        picked = replace(res, ckpt=ckpt)
        theta = r.test_designs(t, s)
        key = f"{run_all.score_key(r, t, s, 'ges')}-picked"
        run_all.cached_scores(r, key, lambda tr: ges.routed_evaluator(picked, policies.ScoreSpecialist(
            t, space, r.preset, workers, trace=tr))(theta), space.full(theta))
        chosen[f"{t}-{s}"] = best
    write_json(os.path.join(r.out, "picked.json"), chosen)
    return chosen


def lever_folder(work: str, lever: str) -> str:
    """Where a lever's GES runs and scores are: the lever "run" is the run's own GES (prepare's --ges-runs)."""
    return work if lever == RUN else os.path.join(work, lever)


def lever_preset(preset, sets: list, cells):
    """The run's preset with a lever's --set overrides (runkit.cli.override, checked there) on the screen's cells."""
    return replace(override(preset, sets)[0], cells=tuple(cells))


def lever_run(work: str, lever: str, workers: int = 1) -> run_all.Run:
    """A lever already run here (or "run", the run's own GES) as run_all sees it: its folder, the run's preset
    with the lever's --set overrides, the run's seed."""
    screen, base = read_json(os.path.join(work, "screen.json")), base_run(work)
    if lever != RUN and lever not in screen["levers"]:
        raise cli_args.BadArg(f"--lever {lever}: not run yet; one of {', '.join([RUN, *screen['levers']])}")
    return replace(base, out=lever_folder(work, lever), workers=workers,
                   preset=lever_preset(base.preset, screen["levers"].get(lever, []), screen["cells"]))


def compared(work: str, r: run_all.Run, t: str, s: str) -> tuple[list, bool]:
    """What a lever's GES is compared with on cell (t, s), as BASES orders them: the e2e MLP, the step-matched
    e2e MLP (the lever's own if it trained one at its steps: True) and the run's own GES, scored at prepare; then
    lever `same`'s GES where it ran (else the run's; none for `same` itself)."""
    own = scores(r.out, run_all.score_key(r, t, s, run_all.MATCHED)) if r.out != work else None
    base = base_run(work)   # the run's own keys (a lever may change K, and so its GES's name)
    found = [own if m == run_all.MATCHED and own is not None else scores(work, run_all.score_key(base, t, s, m))
             for m in BASES]
    if r.out == lever_folder(work, SAME):
        return found + [None], own is not None
    same = scores(lever_folder(work, SAME), run_all.score_key(base, t, s, "ges")) if r.out != work else None
    return found + [same if same is not None else found[-1]], own is not None


def scores(folder: str, key: str) -> np.ndarray | None:
    path = os.path.join(folder, "scores", f"{key}.json")
    return np.array(read_json(path)["scores"]) if os.path.exists(path) else None


def table(works: list) -> str:
    """Per seed, lever and cell: GES's mean J and its paired difference to the e2e MLP, the step-matched e2e MLP,
    the run's own GES (as scored at prepare) and the run's schedule rerun here (lever `same`: the lever's own
    effect; without it the run's GES, which a rerun on the run's CPU model repeats byte for byte), with each
    lever's steps per specialist (the rounds its GES ran)."""
    lines = ["| seed | lever | cell | steps per specialist | GES | GES - e2e MLP | GES - step-matched | "
             "GES - run's GES | GES - `same` |", "|---" * 9 + "|"]
    for work in works:
        screen = read_json(os.path.join(work, "screen.json"))
        for lever, sets in [(RUN, []), *screen["levers"].items()]:
            r = lever_run(work, lever)
            for t, s in r.cells():
                (others, own), steps = compared(work, r, t, s), None
                for suffix in ("-picked",) if lever == RUN else ("", "-picked"):   # the lever, then picked (pick)
                    g = scores(r.out, run_all.score_key(r, t, s, "ges") + suffix)
                    if g is None:
                        continue
                    if steps is None:   # the rounds its GES ran: coverage may stop it before the cap
                        rounds = policies.load_ges(r.path("ges", r.main_ges(t, s))).rounds
                        steps = r.preset.ges_steps(r.preset.ges_trained(rounds))
                    cols = [fmt(paired_comparison(g, o)) if o is not None else "-" for o in others]
                    how = ", ".join(sets) or "as run"
                    how += "; round 0 the run's" if lever in screen.get("round0_reused", []) else ""
                    how += "; step-matched at its steps" if own else ""
                    lines.append(f"| {r.seed} | {lever}{' + pick' if suffix else ''} ({how}) "
                                 f"| {t} {s.upper()} | {steps:,} | {g.mean():.1f} | " + " | ".join(cols) + " |")
    return "\n".join(lines) + "\n"


def split(work: str, lever: str) -> str:
    """Per specialist of a lever: the test designs the lever's router (eq. 10) hands it, and J there of the lever's
    GES, the run's own GES, lever `same`'s (as `compared`), the step-matched e2e MLP (the lever's own if it trained
    one) and the e2e MLP: which specialist and territory hold GES back. The run's GES routes by its own
    territories, which differ where the lever refit them."""
    r = lever_run(work, lever)
    lines = ["| seed | cell | specialist | designs | GES (lever) | run's GES | `same` | step-matched | e2e MLP |",
             "|---" * 9 + "|"]
    for t, s in r.cells():
        res = policies.load_ges(r.path("ges", r.main_ges(t, s)))
        route = res.route(r.test_designs(t, s))
        (mlp, matched, run_ges, same), _ = compared(work, r, t, s)
        got = [scores(r.out, run_all.score_key(r, t, s, "ges")), run_ges, same, matched, mlp]
        for k in range(len(res.ckpt)):
            i = route == k
            cols = [f"{g[i].mean():.1f}" if g is not None and i.any() else "-" for g in got]
            lines.append(f"| {r.seed} | {t} {s.upper()} | {k} | {int(i.sum())} | " + " | ".join(cols) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = cli_args.program("python -m experiments.ges_screen", __doc__)
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = cli_args.command(sub, "prepare", "a work folder from a committed run: warm starts, comparison scores", __doc__)
    p.add_argument("run_folder")
    p.add_argument("--state", required=True, help="COMMIT:PATH of the run's resume state (folder or .tar)")
    p.add_argument("--ges-runs", help="a folder holding the run's GES runs (experiments.ges_territories extract)")
    p.add_argument("--cells", default=",".join(CELLS), help=f"cells to screen (default {','.join(CELLS)})")
    p.add_argument("--out", required=True)
    cli_args.add_workers(p)
    p = cli_args.command(sub, "run", "one lever: GES with --set overrides on the screen's cells, then J", __doc__)
    p.add_argument("work")
    p.add_argument("--lever", required=True, help="the lever's name (its folder)")
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE", help="run_all's preset overrides")
    p.add_argument("--reuse-round0", action="store_true", help="start from the run's own round-0 specialists")
    p.add_argument("--matched", action="store_true", help="also the step-matched e2e MLP at this lever's steps")
    cli_args.add_workers(p)
    p = cli_args.command(sub, "pick", "after a lever: each specialist's policy picked across rounds, then J", __doc__)
    p.add_argument("work")
    p.add_argument("--lever", required=True)
    p.add_argument("--designs", type=cli_args.positive, default=12, help="designs of each final territory (12)")
    cli_args.add_workers(p)
    p = cli_args.command(sub, "split", "a lever's J per specialist, on the test designs it is routed", __doc__)
    p.add_argument("work")
    p.add_argument("--lever", required=True)
    p = cli_args.command(sub, "table", "every lever against the e2e MLP, step-matched and the run's GES", __doc__)
    p.add_argument("works", nargs="+")
    p.add_argument("--out", help="also write the table to this Markdown file")
    a = cli_args.parse(ap, argv)
    try:
        if a.cmd == "prepare":
            prepare(a.run_folder, a.state, os.path.expanduser(a.out), a.ges_runs and os.path.expanduser(a.ges_runs),
                    tuple(c for c in a.cells.split(",") if c), a.workers)
        elif a.cmd == "run":
            run(os.path.expanduser(a.work), a.lever, a.set, a.workers, a.reuse_round0, a.matched)
        elif a.cmd == "pick":
            print(pick(os.path.expanduser(a.work), a.lever, a.designs, a.workers))
        elif a.cmd == "split":
            sys.stdout.write(split(os.path.expanduser(a.work), a.lever))
        else:
            text = table([os.path.expanduser(w) for w in a.works])
            if a.out:
                open(a.out, "w").write(text)
            sys.stdout.write(text)
    except cli_args.BadInput as e:
        print(f"ges_screen: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
