"""experiments/ballu_bench.py -- the simulator's throughput beside the previous robot's; ballu.py's command line.

    python ballu.py bench [--envs 32] [--workers 2]    # or: python -m experiments.ballu_bench bench
    python ballu.py strip --out strip.png [--task obstacle --level 30 --design gcr=0.86,spcf=0.008 --period 12]

`bench` prints robot-physics-steps/s (200 Hz): a sweep over lanes per PyBullet world on one core, the default robot
beside PREVIOUS_ROBOT on one core and on `--workers` workers, and `ballu.score` on 1 and on `--workers` workers.
Results and their reading: docs/speed/README.md. [ours] throughout. `strip`: report.strip.motion_strip of a pump
gait.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace

import numpy as np

import ballu
from ballu import (ACT_DIM, BASELINE, HARDWARE_DRAG, MAX_LEVEL, TASKS, BalluConfig, BalluEnv, PumpGait, VecBallu,
                   score)
from experiments import args
from report.strip import motion_strip

# The robot before the simulator matched the authors' current one: balloon drag, 45 deg spring preload, each
# surface's friction as its material alone (robot 1.0), no passive damping, fixed 8 substeps in worlds of 4 lanes.
# Kept to measure against (this bench, docs/capability), not as an option to train with.
PREVIOUS_ROBOT = dict(drag_coef=HARDWARE_DRAG, spring_preload=math.pi / 4, friction_ground=0.5,
                      friction_ramp=0.8, passive_damping=0.0, substeps=8, substeps_fine=8, lanes_per_world=4)


def _bench_steps(env, steps: int, seed: int):
    """Step `env` (here or inside a worker) with uniform random actions; (time inside stepSimulation, wall)."""
    rng = np.random.default_rng(seed)
    sim0, t0 = env.sim_seconds, time.perf_counter()
    for _ in range(steps):
        env.step(rng.uniform(0, 1, (env.num_envs, ACT_DIM)))
    return env.sim_seconds - sim0, time.perf_counter() - t0


def _bench_env(lanes: int, workers: int, steps: int, cfg: BalluConfig):
    """Robot-physics-steps/s (200 Hz) of `lanes` lanes per worker, each worker stepping its own lanes:
    (physics only = steps / time inside stepSimulation, env with all per-step work = steps / wall)."""
    n = lanes * workers
    env = BalluEnv(n, cfg) if workers == 1 else VecBallu(n, workers, cfg)
    try:
        env.reset(seed=0, options={"designs": BASELINE, "levels": 10})
        if workers == 1:
            out = [_bench_steps(env, steps, 0)]
        else:
            out = env.run(_bench_steps, [(steps, k) for k in range(workers)])
    finally:
        env.close()
    sim, wall = np.max(np.array(out), axis=0)   # the slowest worker sets the pace
    robot_steps = n * steps * cfg.decimation
    return robot_steps / sim, robot_steps / wall


def _bench_score(designs: int, workers: int, cfg: BalluConfig):
    """Robot-physics-steps/s of `score` (pump gaits of 16 periods, 2 short episodes per design)."""
    periods = np.resize(np.arange(4, 36, 2), designs)
    t0 = time.perf_counter()
    score(PumpGait(periods), np.tile(BASELINE, (designs, 1)), cfg.task, episodes=2, start_level=10,
          workers=workers, cfg=cfg)
    return designs * 2 * cfg.episode_steps * cfg.decimation / (time.perf_counter() - t0)


def bench(lanes: int = 16, workers: int = 2, control_steps: int = 200, repeats: int = 2):
    """Simulator throughput next to references measured in the same run.

    Physics only: the time inside stepSimulation alone while the same robots move under random actions. Env:
    all per-step work (forces, torques, state reads, reward, observation). Rates are robot-physics-steps/s
    at 200 Hz. The reference is PREVIOUS_ROBOT (fixed 8 substeps in worlds of 4 lanes), stepped the same way.
    Each configuration is measured `repeats` times in alternation (this machine drifts +-20 % within minutes)
    and the mean is printed. Pool start-up is paid before the scoring rows (the pool is long-lived, so that is
    how `run_all.py` sees it).
    """
    base = BalluConfig()
    before = replace(base, **PREVIOUS_ROBOT)
    sweep = [b for b in (1, 2, 4, 8, 16) if b <= lanes]
    rows = {}
    for _ in range(repeats):
        for b in sweep:
            rows.setdefault(("layout", b), []).append(_bench_env(lanes, 1, control_steps, replace(base, lanes_per_world=b)))
        rows.setdefault(("before", 1), []).append(_bench_env(lanes, 1, control_steps, before))
        rows.setdefault(("env", workers), []).append(_bench_env(lanes, workers, control_steps, base))
        rows.setdefault(("before", workers), []).append(_bench_env(lanes, workers, control_steps, before))
    short = replace(base, episode_steps=100)
    _bench_score(workers, workers, short)   # start the shared pool
    for _ in range(repeats):
        for w in (1, workers):
            rows.setdefault(("score", w), []).append((_bench_score(lanes * workers, w, short),))
    m = {k: np.mean(v, axis=0) for k, v in rows.items()}
    print(f"layout sweep, {lanes} lanes on 1 core        physics only   env, all per-step work")
    for b in sweep:
        raw, env = m[("layout", b)]
        tag = "   <- BalluConfig.lanes_per_world" if b == base.lanes_per_world else ""
        print(f"  {lanes // b:2d} world(s) of {b:2d} lane(s)            {raw:10,.0f}/s {env:14,.0f}/s{tag}")
    raw1, env1 = m[("layout", base.lanes_per_world)]
    raw2, env2 = m[("env", workers)]
    rawb1, envb1 = m[("before", 1)]
    rawb2, envb2 = m[("before", workers)]
    s1, s2 = m[("score", 1)][0], m[("score", workers)][0]
    print(f"1 core, {lanes} lanes:               physics only {raw1:8,.0f}/s   env {env1:8,.0f}/s")
    print(f"  previous robot (8 substeps):   physics only {rawb1:8,.0f}/s   env {envb1:8,.0f}/s   "
          f"-> default {raw1 / rawb1:.2f}x physics, {env1 / envb1:.2f}x env")
    print(f"{workers} workers, {lanes} lanes each:     physics only {raw2:8,.0f}/s   env {env2:8,.0f}/s")
    print(f"  previous robot (8 substeps):   physics only {rawb2:8,.0f}/s   env {envb2:8,.0f}/s   "
          f"-> default {raw2 / rawb2:.2f}x physics, {env2 / envb2:.2f}x env")
    print(f"score, {lanes * workers} designs:          1 core {s1:8,.0f}/s   {workers} workers {s2:8,.0f}/s")
    print(f"env/physics ratio {env1 / raw1:.2f}   (1 core, all per-step work / stepSimulation alone)")
    print(f"{workers} workers vs 1 core {env2 / env1:.2f}x   (env: each worker steps its own lanes, as ppo.train)")
    print(f"{workers} workers vs 1 core {s2 / s1:.2f}x   (score: each worker plays its designs)")
    print(f"({repeats} alternating repeats each; robot-physics-steps per second at 200 Hz; default: adaptive "
          f"{base.substeps}/{base.substeps_fine} substeps, previous robot: experiments.ballu_bench.PREVIOUS_ROBOT)")
    return m


OLD_FLAGS = {"--bench": ("bench", False), "--strip": ("strip", True)}   # before issue 97: the flags, deprecated


def parser() -> argparse.ArgumentParser:
    ap = args.program("python ballu.py", __doc__, ballu.__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    b = args.command(sub, "bench", "print simulator throughput", __doc__)
    b.add_argument("--envs", type=int, help="lanes in all, split evenly over --workers (default: 16 per worker)")
    args.add_workers(b)
    st = args.command(sub, "strip", "write a motion strip (PNG) of one pump-gait episode", __doc__)
    st.add_argument("--out", required=True, metavar="PNG", help="the PNG to write")
    st.add_argument("--task", default="obstacle", choices=TASKS)
    st.add_argument("--level", type=int, default=30, help=f"terrain level of the strip, 0..{MAX_LEVEL}")
    st.add_argument("--design", type=args.full_design_type, default=BASELINE, help=args.DESIGN_HELP
                    + "; default baseline")
    st.add_argument("--period", type=int, default=12, help="pump gait period in control steps (>= 2)")
    st.add_argument("--mode", default="sync", choices=("sync", "alternate"), help="pump gait mode")
    return ap


def main(argv=None):
    """The command line of `python ballu.py` and of this module: bench, or strip --out PNG."""
    ap = parser()
    a = args.parse(ap, argv, OLD_FLAGS)
    if a.cmd == "bench":
        if a.workers < 1:
            ap.error(f"--workers {a.workers} must be >= 1")
        envs = 16 * a.workers if a.envs is None else a.envs
        if envs < a.workers or envs % a.workers:
            ap.error(f"--envs {envs} must be a multiple of --workers {a.workers} (each worker steps as many lanes)")
        bench(envs // a.workers, a.workers)
        return 0
    for opt, value, rule, ok in (("--level", a.level, f"in [0, {MAX_LEVEL}]", 0 <= a.level <= MAX_LEVEL),
                                 ("--period", a.period, ">= 2", a.period >= 2)):
        if not ok:
            ap.error(f"{opt} {value} must be {rule}")
    try:
        print("wrote", motion_strip(a.out, PumpGait(a.period, a.mode), a.task, a.level, a.design))
    except OSError as e:
        ap.error(f"--out {a.out!r} cannot be written: {e.strerror}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
