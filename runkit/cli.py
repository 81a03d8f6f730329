"""A run made of stages, from its command line: the arguments and the output folder checked before anything is
written, a resumed run's work files read back first (repair), each stage run once with its wall time, its result
kept in stages/<name>.json, the ETA after each and the report at the end; `--plan` and `--rates` (runkit.plan,
with the run's calibration); kill_hook, where the resume tests simulate a kill. Knows no BALLU or GES: the
experiment (run_all.EXPERIMENT) names its presets, stages, runs, report, rate job and work files."""
from __future__ import annotations

import argparse
import functools
import json
import os
import sys
import time
from dataclasses import MISSING, asdict, dataclass, fields, replace
from typing import Callable

from runkit.clock import StageClock, stage_times
from runkit.files import READ_ERRORS, BadInput, read_back, read_json, redo_if_damaged, write_json
from runkit.folder import check_ours, check_output, code_hash, git_commit, open_output
from runkit.plan import (CALIBRATION_FILE, CALIBRATION_STEPS, Layout, calibrate, calibration_for, measure_rates,
                         plan_seconds, plan_text, rates_text)
from runkit.pool import StopBy, clock_text, close_dask_clients, dask_client, stop_time
from runkit.progress import run_eta, say


@dataclass(frozen=True)
class Experiment:
    """What the command line runs (run_all.EXPERIMENT). A run is `Run(out, preset, seed, workers, executor,
    scheduler, stop_by)`, a dataclass with path(*parts), pool() (the executor of its jobs), out, preset and
    workers; a preset a frozen dataclass with a name and the budgets runkit.plan reads."""
    tool: str              # the program's name in error lines and the manifest ("run_all.py")
    description: str       # --help's first line
    home: str              # the checkout: its git commit, results/<preset> (the default --out), the files below
    presets: dict          # name -> preset
    default_preset: str
    stages: dict           # name -> (fn(run) -> the stage's JSON result, names of the stages it needs), in run order
    layout: Layout         # what every run is made of besides its budgets (--plan)
    Run: Callable
    rate_job: Callable     # (folder, kind, task, seed, preset=, steps=, n_designs=): runkit.plan.measure_rates
    report: Callable       # (run, manifest) -> REPORT.md's text, from whatever stages have finished
    repair: Callable       # (run): read back the stages' work files before a resumed run (repair does the rest)
    results_format: int    # bumped when what a stage computes or stores changes: old result folders are refused
    numbers: tuple         # the files under `home` that produce the numbers, hashed (runkit.folder.code_hash)
    files: tuple           # the files under `home` a Dask cluster started by hand gets (runkit.pool.dask_client)
    examples: str = ""     # --help's epilog: example command lines


# ----------------------------------------------------------------------------------------------------------
# A stage: its result, run once, and the hook where tests simulate a kill
# ----------------------------------------------------------------------------------------------------------
def stage_json(path: str):
    return read_json(path)["result"]


def stage_result(run, name: str):
    """A finished stage's result, None if it has not finished (repair moved a damaged one aside)."""
    path = run.path("stages", f"{name}.json")
    return read_back(path, stage_json, fix=f"delete it to redo stage {name}") if os.path.exists(path) else None


def stage_done(out: str, name: str) -> bool:
    """A stage's result is there and readable (a damaged one is redone: repair)."""
    path = os.path.join(out, "stages", f"{name}.json")
    try:
        return os.path.exists(path) and stage_json(path) is not None
    except READ_ERRORS:
        return False


def run_stage(run, name: str, fn) -> float:
    """Run stage `name` (fn(run) -> its result) unless its result exists; record its wall time (summed over
    attempts); returns the seconds it ran (0 if skipped)."""
    path = run.path("stages", f"{name}.json")
    if stage_result(run, name) is not None:
        say(f"stage {name}: done already, skipped")
        return 0.0
    say(f"stage {name}: start")
    clock = StageClock(run.path("stage_seconds.json"), name)
    try:
        result = fn(run)
    finally:
        seconds = clock.close()
    write_json(path, {"stage": name, "result": result})
    say(f"stage {name}: done in {seconds:.1f}s")
    return seconds


def kill_hook(tag: str) -> None:
    """Test hook: RUN_ALL_FAIL_AT=<tag> raises here, simulating a kill at that point of a stage."""
    if os.environ.get("RUN_ALL_FAIL_AT") == tag:
        raise RuntimeError(f"simulated kill at {tag}")


def repair(run, exp: Experiment) -> None:
    """Before a resumed run's stages: read back every work file it may use. What can be redone exactly (a stage's
    result, timing records; the experiment's work files: exp.repair) is moved aside and redone, with a warning."""
    for name in exp.stages:
        redo_if_damaged(run.path("stages", f"{name}.json"), stage_json, part=f"redoing stage {name}")
    stage_times(run.path("stage_seconds.json"))
    exp.repair(run)


def calibration(run, rate_job=None) -> dict | None:
    """The rates `run` is planned at (runkit.plan.calibrate): its folder's calibration, or one measured now with
    `rate_job` (< 60 s) and kept there, so `--plan` and the run it plans use one measurement. None (the plan's
    constants) without `rate_job`, or for a preset whose policies train fewer steps than a calibration job (smoke):
    measuring would cost more than the run trains."""
    batch, path = (run.preset.ppo_envs, run.preset.ppo_rollout), run.path(CALIBRATION_FILE)
    try:
        cal = calibration_for(read_json(path) if os.path.exists(path) else None, run.workers, batch)
    except (OSError, *READ_ERRORS):   # a damaged calibration is measured anew
        cal = None
    if cal or rate_job is None or run.preset.ppo_steps < CALIBRATION_STEPS:
        return cal
    check_ours(run.out)   # somebody else's folder is refused before anything is written
    say(f"calibrating the plan's rates on this machine: {run.workers} job(s) side by side, < 60 s")
    load = os.getloadavg()[0]   # [ours] a calibration beside other work plans the run long, and is kept
    if load >= 0.5:
        say(f"warning: load average {load:.1f} on {os.cpu_count()} cores before calibrating: other work shares "
            f"the CPU, so the plan will run long; to measure again on an idle machine, delete {path}")
    job = functools.partial(rate_job, preset=run.preset, steps=CALIBRATION_STEPS, n_designs=1)
    cal = calibrate(job, replace(run, stop_by=None).pool(), run.workers, batch)
    os.makedirs(run.out, exist_ok=True)
    write_json(path, cal)
    say(f"calibrated: PPO {cal['train_rate']:.0f}, score {cal['score_rate']:.0f} control steps/s per job, in "
        f"{cal['seconds']:.0f} s: {path}")
    return cal


# ----------------------------------------------------------------------------------------------------------
# The command line: check the arguments and the output folder, run the stages, write the report
# ----------------------------------------------------------------------------------------------------------
def override(preset, items: list):
    """The preset with `--set FIELD=VALUE` overrides applied (value typed by the field: int, float, str, bool,
    tuple as comma-separated values, `none` where the field may be None); BadInput names a bad field or value."""
    kinds = {f.name: str(f.type) for f in fields(preset) if f.name != "name"}
    changes = {}
    for item in items:
        name, eq, text = item.partition("=")
        if not eq or name not in kinds:
            raise BadInput(f"--set {item!r}: expected FIELD=VALUE with FIELD one of {', '.join(kinds)}")
        kind = kinds[name]
        try:
            if text.lower() == "none" and "None" in kind:
                value = None
            elif kind.startswith("tuple"):
                value = tuple(_scalar(v) for v in text.split(",") if v)
            elif kind.startswith("bool"):
                value = {"true": True, "false": False}[text.lower()]
            else:
                kind0 = kind.split()[0]   # 1_000 reads as 1000; a string is kept as typed
                value = text if kind0 == "str" else {"int": int, "float": float}[kind0](text.replace("_", ""))
        except (ValueError, KeyError):
            raise BadInput(f"--set {name}={text!r}: not a value of type {kind}") from None
        if isinstance(value, float) and not 0 <= value <= 1:   # the preset's float fields are fractions
            raise BadInput(f"--set {name}={text}: must be in [0, 1]")
        if isinstance(value, int) and not isinstance(value, bool) and value < (0 if "level" in name else 1):
            raise BadInput(f"--set {name}={text}: must be >= {0 if 'level' in name else 1}")
        changes[name] = value
    try:
        return replace(preset, **changes), changes   # the preset checks itself (runkit.settings.need)
    except ValueError as e:
        raise BadInput(f"--set {e}") from None


def _scalar(text: str):
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return text


def parse(argv, exp: Experiment):
    ap = argparse.ArgumentParser(description=exp.description, epilog=exp.examples,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", default=exp.default_preset, choices=tuple(exp.presets),
                    help=f"budgets (default: {exp.default_preset})")
    ap.add_argument("--plan", action="store_true", help="print the preset's work per stage and its hours on "
                    "--workers cores at this machine's rates: --out's calibration.json, or measured now (< 60 s) "
                    "and kept there for the run; then exit")
    ap.add_argument("--rates", action="store_true", help="measure the rates at length with the preset's batch: an "
                    "e2e MLP and MoE on each task, --workers side by side, each training 40,960 PPO steps and "
                    "scoring 3 designs (~4 min), beside the constants a run without calibration is planned at")
    ap.add_argument("--only", default="", help=f"comma-separated stages out of {','.join(exp.stages)}")
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                    help="override one budget of the preset, e.g. --set n_test=10 --set ksens_K=1,3 (repeatable; "
                         "kept in the manifest and REPORT.md; a resumed run with other values is refused)")
    ap.add_argument("--out", default=None, help="output folder (default: results/<preset>)")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="processes (default: every core)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--fresh", action="store_true", help="delete this run's earlier results and start over")
    ap.add_argument("--stop-by", default=None, metavar="HH:MM",
                    help="no job starts after this time of day (its next occurrence); jobs under way finish, then "
                         "the run stops (exit 3); a rerun goes on with an uninterrupted run's numbers, as after a "
                         "kill, but without redoing the work a kill cuts off (a training's updates since its last "
                         "checkpoint, a score under way)")
    ap.add_argument("--executor", default="process", choices=("process", "dask"),
                    help="independent jobs on a local process pool (default) or a Dask cluster")
    ap.add_argument("--scheduler", default=None, metavar="ADDRESS",
                    help="Dask scheduler, e.g. tcp://HOST:8786 (default with --executor dask: a local cluster "
                         "of --workers processes)")
    return ap.parse_args(argv)


def check_args(args, exp: Experiment) -> list:
    """Validate everything before anything is written; BadInput -> exit code 2."""
    stages = exp.stages
    only = [s for s in args.only.split(",") if s] if args.only else list(stages)
    bad = [s for s in only if s not in stages]
    if bad:
        raise BadInput(f"unknown stage(s) {bad} in --only; known: {','.join(stages)}")
    if not only:
        raise BadInput(f"--only {args.only!r} names no stage; known: {','.join(stages)}")
    if args.seed < 0:
        raise BadInput(f"--seed={args.seed} must be >= 0")
    if args.scheduler and args.executor != "dask":
        raise BadInput(f"--scheduler {args.scheduler} needs --executor dask")
    if args.executor == "dask":
        try:
            import distributed  # noqa: F401
        except ImportError:
            raise BadInput("--executor dask needs the 'distributed' package (pip install distributed)") from None
        if args.scheduler:   # connect now: a wrong address fails before anything is written
            dask_client(args.scheduler, args.workers, [os.path.join(exp.home, f) for f in exp.files])
    return [s for s in stages if s in only]


def check_needs(out: str, stages: list, exp: Experiment, reuse: bool) -> None:
    """Each requested stage's inputs must be finished already (readable) or be requested before it."""
    have = {n for n in exp.stages if reuse and stage_done(out, n)}
    for name in stages:
        missing = [n for n in exp.stages[name][1] if n not in have]
        if missing:
            damaged = [f"stages/{n}.json" for n in missing if os.path.exists(os.path.join(out, "stages", f"{n}.json"))]
            raise BadInput(f"stage {name} needs stage(s) {missing} first (run them too, or drop --only)"
                           + (f"; {', '.join(damaged)} is damaged" if damaged else ""))
        have.add(name)


def main(argv, exp: Experiment) -> int:
    """The command line of the experiment `exp` (run_all.main): exit code 0, 2 (bad input) or 3 (--stop-by)."""
    args = parse(argv, exp)
    preset = exp.presets[args.preset]
    out = os.path.abspath(args.out or os.path.join(exp.home, "results", preset.name))
    try:
        preset, overrides = override(preset, args.set)
        if args.workers < 1:
            raise BadInput(f"--workers {args.workers} must be >= 1")
        stop_by = stop_time(args.stop_by) if args.stop_by else None
        if args.plan:
            cal = calibration(exp.Run(out, preset, args.seed, args.workers, args.executor, args.scheduler),
                              exp.rate_job)
            print(plan_text(preset, exp.layout, args.workers, cal), flush=True)
            return 0
        if args.rates:
            job, pool = functools.partial(exp.rate_job, preset=preset), exp.Run("", preset, 0, args.workers).pool()
            print(rates_text(measure_rates(job, pool, args.workers)), flush=True)
            return 0
        stages = check_args(args, exp)
        manifest = {"tool": exp.tool, "results_format": exp.results_format, "preset": preset.name,
                    "budgets": json.loads(json.dumps(asdict(preset))), "seed": args.seed,
                    **({"overrides": json.loads(json.dumps(overrides))} if overrides else {}),
                    "code_hash": code_hash(exp.home, exp.numbers, exp.results_format),
                    "git_commit": git_commit(exp.home), "created": time.strftime("%Y-%m-%d %H:%M:%S")}
        defaults = json.loads(json.dumps({f.name: f.default for f in fields(preset) if f.default is not MISSING}))
        reuse = check_output(out, manifest, args.fresh, defaults)
        check_needs(out, stages, exp, reuse)
        manifest = open_output(out, manifest, reuse)
        run = exp.Run(out, preset, args.seed, args.workers, args.executor, args.scheduler, stop_by)
        if reuse:
            repair(run, exp)
        t0 = time.time()
        say(f"preset {preset.name}, seed {args.seed}, {args.workers} worker(s) ({args.executor}), output {out}, "
            f"stages {stages}" + (f"; no job starts after {clock_text(stop_by)}" if stop_by else ""))
        planned = plan_seconds(preset, exp.layout, args.workers, calibration(run, exp.rate_job))
        todo, ran = [s for s in stages if not stage_done(out, s)], {}
        recorded = functools.partial(stage_times, run.path("stage_seconds.json"))
        if todo:
            say(run_eta(planned, ran, todo, recorded()))
        try:
            for name in stages:
                if run_stage(run, name, exp.stages[name][0]):
                    times = recorded()
                    ran[name] = times.get(name, 0.0)
                    todo.remove(name)
                    if todo:
                        say(f"{run_eta(planned, ran, todo, times)}; elapsed {time.time() - t0:.0f}s")
        finally:
            close_dask_clients()
            exp.report(run, manifest)
        say(f"all requested stages done in {time.time() - t0:.1f}s; see {os.path.join(out, 'REPORT.md')}")
        return 0
    except BadInput as e:
        print(f"{exp.tool}: error: {e}", file=sys.stderr)
        return 2
    except StopBy as e:
        say(f"stopped: {e} (--stop-by); the jobs under way finished and are kept: rerun the same command to go on")
        return 3
    finally:
        close_dask_clients()   # a client connected by check_args, if a later check failed
