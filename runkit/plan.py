"""What a preset costs: the arithmetic behind every preset's wall time (`run_all.py --plan`), at rates measured on
the machine the run goes on (a short calibration kept in the output folder) or at `--rates`' longer measurement.
It reads a preset's numbers and the run's Layout (what every run is made of, counted), so it knows nothing of
BALLU or GES; the numbers behind each constant: docs/presets.md."""
from __future__ import annotations

import math
import os
import platform
import shutil
import tempfile
import time
from dataclasses import dataclass

import numpy as np

from runkit.logs import read_log

# [ours] per-core rates in control steps/s as run_all runs its jobs (one single-process job per core, both cores
# busy, each kind of policy on each task), measured by `python run_all.py --rates` on one machine: the plan's
# rates where no calibration of the run's own machine is at hand (docs/presets.md). VMs of one kind differ ~2x.
TRAIN_RATE, SCORE_RATE = 880.0, 840.0
# [ours] a run's policies train at this share of a calibration's (or --rates') PPO rate: those jobs time fresh
# policies for a few updates, a run's policies learn to walk, and a walking gait steps slower (its contacts and
# fast joints take ballu's finer substeps). The quick run trained at 0.81x its calibration: fresh policies' first
# updates 0.90x, their last 0.81x, warm-started GES specialists 0.77x; planned at 0.81x, every stage but the 48 s
# of figures came within 10 % of its plan, the whole run at 0.98x (docs/quick/RUN.md).
TRAINED_SHARE = 0.81
# [ours] share of a J's episodes that ballu.score plays (`reuse` replays the rest exactly): the larger of two
# measurements, since the plan is an upper bound (docs/presets.md). The step counts stay every episode's.
SCORE_PLAYED = 0.66
# [ours] how much faster a job runs while the other cores idle than beside busy ones: 2 workers do 1.68x one
# (`python ballu.py bench`, docs/speed), so a lone job on 2 cores runs 2 / 1.68 = 1.19x the per-core rate;
# checked against measured stages in docs/presets.md ("How jobs pack onto the cores").
ALONE_SPEEDUP = 2 / 1.68
# [ours] fixed costs that only matter for tiny presets: a process pool's start (its spawned processes import
# torch and pybullet), once per pool a stage starts, and the figures stage (docs/presets.md).
POOLS = {"baselines": 1, "ges": 1, "matched": 1, "table2": 2, "table3": 2, "ksens": 2, "cost": 1}
POOL_START_S, FIGURES_S = 2.0, 40.0


@dataclass(frozen=True)
class Layout:
    """What every run is made of besides its preset's budgets, counted (run_all.LAYOUT)."""
    tasks: int           # each with a policy of its baseline design
    spaces: int          # design spaces per task: a (task, space) pair is a cell
    e2e: int             # end-to-end policies per cell (e2e MLP, e2e MoE)
    methods: int         # methods scored on a cell's test designs
    searched: int        # methods with a TPE design search per cell
    episode_steps: int   # control steps of one episode
    ksens_cell: str = "obstacle-d2"   # the cell of Table III and Fig. 7


def played_share(preset) -> float:
    """Share of a J's episodes that score plays (SCORE_PLAYED); one episode has nothing to reuse."""
    return SCORE_PLAYED if preset.score_episodes > 1 else 1.0


def plan(preset, layout: Layout, workers: int = 2, train_rate: float = TRAIN_RATE,
         score_rate: float = SCORE_RATE) -> dict:
    """Upper bound of a preset's work per stage, in control steps: PPO training, scores J (test designs, TPE
    trials) and GES probes, and the hours on `workers` cores at the given per-core rates, scores at the share of
    episodes that score's reuse plays (SCORE_PLAYED). Jobs pack onto the cores as the stages run them: a stage's
    GES runs go side by side, their specialists of a round `workers` at a time (Table III's one other run of K = 3
    on 2 cores: two waves, a core idle in the second), Table III's and Fig. 7's score sets side by side,
    per-design BO's random startup trials `workers` at a time and its TPE trials one at a time; everything else
    packs perfectly.
    GES runs are counted at their round cap (a run that reaches the target coverage stops earlier). Fixed costs
    that only matter for tiny presets (smoke): each process pool a stage starts (POOLS, with workers > 1) and the
    figures stage (FIGURES_S)."""
    p, episode = preset, getattr(preset, "episode_steps", None) or layout.episode_steps   # a preset's own first
    J = p.score_episodes * episode                                            # one design's score J
    peak_J = (p.peak_episodes or 0) * episode                                  # a TPE peak scored once more
    probe_J = len(p.probe_level_steps) * episode if p.probe_level_steps else J

    spec = p.ges_steps(p.ges_max_rounds + int(getattr(p, "ges_final_train", False)))   # a specialist's, at the cap

    def ges(Ks):   # (PPO steps, 0, probe steps) of GES runs with these K, each at its round cap
        return np.array([sum(K * spec for K in Ks), 0,
                         sum(K * p.ges_probes * probe_J for K in Ks) * p.ges_max_rounds])

    def idle(n):   # jobs' worth of core time n equal jobs leave idle, run `workers` at a time; a last, partial
        # wave's jobs run ALONE_SPEEDUP x faster on the emptier machine
        return workers * (n // workers) + (workers / ALONE_SPEEDUP if n % workers else 0) - n

    # the preset's cells ("<task>-<space>", space d2 or d3: run_all's Preset.cells), else every task in every space
    chosen = getattr(p, "cells", None) or [f"{t}-d{2 + s}" for t in range(layout.tasks) for s in range(layout.spaces)]
    cells, tasks, searched = len(chosen), len({c.rsplit("-", 1)[0] for c in chosen}), layout.searched
    main_K = [p.K_d2 if c.endswith("d2") else p.K_d3 for c in chosen]   # each cell's main GES run
    # Table III and Fig. 7 run on one cell (layout.ksens_cell), the cost on its own (the preset's cost_task/space)
    k_on = not hasattr(p, "cells") or layout.ksens_cell in chosen
    cost_on = not hasattr(p, "cells") or f"{p.cost_task}-{p.cost_space}" in chosen
    other_inits = (len(p.table3_inits) - 1) * k_on                         # fps+lloyd with K_d2: the ges stage's
    other_K = [K for K in p.ksens_K if K != p.K_d2] if k_on else []
    # adaptive K (ksens_auto) counted at its start and bound (ges_auto_K), plus its checks (every specialist
    # scores every territory's): an upper bound, as it merges down
    auto = [p.ges_auto_K()] if getattr(p, "ksens_auto", False) and k_on else []
    checks = sum(K * K * p.ges_n_check() * probe_J for K in auto) * p.ges_max_rounds
    work = {"baselines": np.array([(tasks + layout.e2e * cells) * p.ppo_steps, 0, 0]),
            "ges": ges(main_K),
            # the step-matched e2e MLP: each cell's e2e MLP trained a specialist's steps on (round cap), then scored
            "matched": np.array([cells * spec, cells * p.n_test * J, 0]),
            "table2": np.array([0, (tasks + cells * layout.methods * p.n_test + cells * searched * p.tpe_trials) * J
                                + cells * searched * peak_J, 0]),
            "table3": ges([p.K_d2] * other_inits) + [0, other_inits * p.n_test * J, 0],
            "ksens": ges(other_K + auto) + [0, len(other_K + auto) * p.n_test * J, checks],
            "cost": np.array([p.cost_trials * p.ppo_steps, p.cost_trials * J, 0]) * cost_on, "figures": np.zeros(3)}
    # control steps the idle cores could have done: a stage's GES runs side by side, their specialists in waves
    # of `workers` each round; its score sets side by side
    ges_idle = lambda Ks: np.array([idle(sum(Ks)) * spec, 0, 0])   # noqa: E731
    waste = {"ges": ges_idle(main_K),
             "table3": ges_idle([p.K_d2] * other_inits) + [0, idle(other_inits) * p.n_test * J, 0],
             "ksens": ges_idle(other_K + auto) + [0, idle(len(other_K + auto)) * p.n_test * J, 0]}
    played = played_share(p)
    fixed = {s: POOLS.get(s, 0) * POOL_START_S * (workers > 1) * bool(work[s].any()) + FIGURES_S * (s == "figures")
             for s in work}   # a stage without work (a cell the run leaves out) starts no pool
    # per-design BO's trials run `workers` at a time while random (startup), then one at a time: its width
    startup = min(p.cost_trials, p.tpe_startup)
    width = {"cost": p.cost_trials / (math.ceil(startup / workers) + p.cost_trials - startup)}

    def hours(stage):
        b = work[stage] + waste.get(stage, 0)
        return ((b[0] / train_rate + played * (b[1] + b[2]) / score_rate) / width.get(stage, workers)
                + fixed[stage]) / 3600

    return {stage: {"ppo_steps": int(w[0]), "score_steps": int(w[1]), "probe_steps": int(w[2]),
                    "hours": hours(stage)} for stage, w in work.items()}


def rates_of(cal: dict | None) -> tuple:
    """(train_rate, score_rate) the plan runs at: a calibration's (calibrate), or the constants without one, PPO's
    at the share a run's walking policies train at (TRAINED_SHARE)."""
    train, score = (cal["train_rate"], cal["score_rate"]) if cal else (TRAIN_RATE, SCORE_RATE)
    return TRAINED_SHARE * train, score


def plan_seconds(preset, layout: Layout, workers: int, cal: dict | None = None) -> dict:
    """The plan's seconds per stage at a calibration's rates (the whole run's ETA and REPORT.md's wall-time table
    set these beside)."""
    return {stage: 3600 * v["hours"] for stage, v in plan(preset, layout, workers, *rates_of(cal)).items()}


def rates_source(cal: dict | None) -> str:
    """Where the plan's rates come from, in a line's words."""
    if not cal:
        return "the constants TRAIN_RATE / SCORE_RATE (no calibration of this machine)"
    return (f"calibrated on {cal['cpu']} at {cal['time']} ({len(cal['jobs'])} jobs side by side, "
            f"{cal['seconds']:.0f} s)")


def plan_text(preset, layout: Layout, workers: int = 2, cal: dict | None = None) -> str:
    """--plan's lines: each stage's work and hours at a calibration's rates (or the constants), and the total."""
    train, score = rates_of(cal)
    rows = plan(preset, layout, workers, train, score)
    lines = [f"preset {preset.name} on {workers} core(s) at {train:.0f} PPO / {score:.0f} score control steps/s per "
             f"core (PPO at {TRAINED_SHARE:.2f}x the rate measured, as walking policies train), {rates_source(cal)}; "
             f"scores playing {100 * SCORE_PLAYED:.0f} % of their episodes (GES at its round cap of "
             f"{preset.ges_max_rounds}):"]
    lines += [f"  {k:10s} PPO {v['ppo_steps'] / 1e6:8.2f} M steps   scores {v['score_steps'] / 1e6:8.2f} M   "
              f"probes {v['probe_steps'] / 1e6:8.2f} M   {v['hours']:7.2f} h" for k, v in rows.items()]
    total = sum(v["hours"] for v in rows.values())
    return "\n".join(lines + [f"  {'total':10s} {total:.2f} h = {60 * total:.1f} min "
                              f"({total * workers:.1f} core-hours)"])


# [ours] the jobs `--rates` times, as the stages mix them: each kind of policy on each task (the ramp's contacts
# make its steps dearer than the obstacle's; docs/presets.md).
RATE_JOBS = (("mlp", "obstacle"), ("moe", "ramp"), ("moe", "obstacle"), ("mlp", "ramp"))


def measure_rates(rate_job, executor, workers: int, out: str | None = None, jobs: int | None = None) -> dict:
    """The per-core rates `plan` uses, measured as run_all runs its jobs: `jobs` single-process jobs (default
    RATE_JOBS, each kind on each task) on `executor`, `workers` side by side; `rate_job(folder, kind, task, seed)`
    trains then scores and returns (PPO steps/s, s per J, played score steps/s). SCORE_RATE is the rate of the
    score steps J actually simulated (ballu.score's reuse replays the rest), so it does not depend on how much a
    policy this briefly trained replays; `plan` applies the trained policies' share (SCORE_PLAYED). The jobs'
    folders go under `out` (default: a temporary folder, deleted after)."""
    folder = out or tempfile.mkdtemp(prefix="run_all_rates_")
    todo = [RATE_JOBS[i % len(RATE_JOBS)] for i in range(jobs or max(workers, len(RATE_JOBS)))]
    try:
        futs = [executor.submit(rate_job, os.path.join(folder, f"job{i}"), kind, task, i)
                for i, (kind, task) in enumerate(todo)]
        res = [f.result() for f in futs]
    finally:
        executor.shutdown(wait=True)
        if out is None:
            shutil.rmtree(folder, ignore_errors=True)
    train, per_J, played = [r[0] for r in res], [r[1] for r in res], [r[2] for r in res]
    return {"workers": workers, "jobs": [f"{k} {t}" for k, t in todo], "train_steps_per_s": train,
            "seconds_per_J": per_J, "played_steps_per_s": played, "train_rate": float(np.mean(train)),
            "score_rate": float(np.mean(played))}


def job_rates(train, score, log_csv: str, steps: int, n_designs: int) -> tuple:
    """A rate job's numbers (measure_rates' contract), timed as a stage runs its jobs: `train()` trains a policy for
    `steps` PPO steps, logging to `log_csv`; then `score()` scores `n_designs` designs and returns the control
    steps it played. Returns (PPO steps/s over the updates after the first, s per J, played score steps/s: the
    steps J actually simulated, replays excluded)."""
    t0 = time.time()
    train()
    t1 = time.time()
    played = score()
    scored = time.time() - t1
    rates = read_log(log_csv)["steps_per_s"][1:]   # the first update also builds the env
    rate = len(rates) / np.sum(1.0 / rates) if len(rates) else steps / (t1 - t0)   # as REPORT.md's rate line
    return rate, scored / n_designs, played / scored


def rates_text(r: dict) -> str:
    """--rates' lines: each job's rates, then the measured rates beside the constants --plan uses."""
    jobs = "; ".join(f"{j}: PPO {x:.0f} steps/s, J {y:.1f} s per design ({z:.0f} played steps/s)"
                     for j, x, y, z in zip(r["jobs"], r["train_steps_per_s"], r["seconds_per_J"],
                                           r["played_steps_per_s"]))
    return (f"{len(r['jobs'])} job(s), {r['workers']} side by side: {jobs}\n"
            f"measured TRAIN_RATE {r['train_rate']:.0f}, SCORE_RATE {r['score_rate']:.0f} against the constants "
            f"{TRAIN_RATE:.0f}, {SCORE_RATE:.0f} that --plan uses")


# [ours] a calibration: its file in the output folder, and the PPO steps each of its jobs trains (6 updates of the
# quick and overnight batch; with one design's J after it, 2 jobs side by side take < 60 s, the pool's start
# included: docs/presets.md, "The plan's rates")
CALIBRATION_FILE, CALIBRATION_STEPS = "calibration.json", 12_288


def cpu_model() -> str:
    """The CPU's model name: a calibration names the machine it measured. J is reproducible bit for bit on one
    machine, not across CPU models: their rounding differs and contacts amplify it (one checkpoint, 12 designs:
    mean J 21.0 cm on an AMD EPYC VM, 18.9 on an Intel Xeon VM, 11 designs different), so a comparison's scores
    come from one machine (experiments/ppo_protocol)."""
    try:
        with open("/proc/cpuinfo") as f:
            return next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        return platform.processor() or platform.machine()


def calibrate(rate_job, executor, workers: int, batch: tuple) -> dict:
    """The rates a run is planned at, measured where it runs and as it runs its jobs: `workers` single-process
    jobs side by side (RATE_JOBS' first ones: an e2e MLP on the obstacle, an e2e MoE on the ramp), each training
    briefly then scoring one design (`rate_job` as in measure_rates, its PPO rate over the updates after the first,
    as REPORT.md's rate line counts them). [ours] A constant planned one VM's run 1.5x short, and another VM of the
    same kind benches at half the speed: a minute's measurement plans both (docs/presets.md). `batch` (PPO envs,
    steps per update) is recorded: a calibration is reused only for the same batch and workers (calibration_for)."""
    t0 = time.time()
    r = measure_rates(rate_job, executor, workers, jobs=workers)
    r.update(seconds=time.time() - t0, time=time.strftime("%Y-%m-%d %H:%M"), cpu=cpu_model(), batch=list(batch))
    return r


def calibration_for(cal: dict | None, workers: int, batch: tuple) -> dict | None:
    """A stored calibration if it measured this many workers side by side at this PPO batch, else None."""
    if cal and cal.get("workers") == workers and tuple(cal.get("batch", ())) == tuple(batch):
        return cal
    return None
