"""experiments/ppo_ballu.py -- train one PPO policy on BALLU, or film one, from the command line.

    python -m experiments.ppo_ballu train --out OUT --task obstacle --design baseline --steps 1000000 [--score]
    python -m experiments.ppo_ballu train --out OUT --design gcr=0.86,spcf=0.008 --workers 2
    python -m experiments.ppo_ballu strip --out strip.png --policy OUT/policy.pt --task obstacle --level 16

`train` writes OUT/policy.pt (resumed if it exists), OUT/log.csv and OUT/curve.png; with --score it prints J on
the design (8 uniform designs for --design d2). Every argument is checked before anything is written.
run_all.py trains every policy of the paper itself; this is for one policy at a time (docs/ppo_protocol).
"""
from __future__ import annotations

import argparse
import math
import os
import sys

import numpy as np

import ballu
import ppo
from experiments import args
from report.strip import motion_strip

DESIGN_HELP = f"{args.DESIGN_HELP}; or d2c (D2's centre) or d2 (uniform over D2)"


def design_sampler(text: str):
    """--design: experiments/args.py's form (full_design), or d2c (the centre of D2) or d2 (uniform over D2), the
    designs this study trained on; args.BadArg naming what is wrong otherwise."""
    if text == "d2c":
        return ballu.FixedDesign(ballu.D2_CENTRE)
    if text == "d2":
        return ballu.UniformDesign(ballu.d2())
    return ballu.FixedDesign(args.full_design(text))


def start_levels(text: str):
    """--start-level: a name of ballu.START_LEVEL_NAMES ("task": ballu.train_start_levels, "spread",
    "zero"), "L" or "LOW:HIGH", levels in 0..74 (ballu.MAX_LEVEL), LOW <= HIGH."""
    if text in ballu.START_LEVEL_NAMES:
        return text
    lo, sep, hi = text.partition(":")
    try:
        lv = (int(lo), int(hi)) if sep else (int(lo),)
    except ValueError:
        lv = ()
    if not lv or min(lv) < 0 or max(lv) > ballu.MAX_LEVEL or lv[0] > lv[-1]:
        raise argparse.ArgumentTypeError(f"{text!r} is not one of {', '.join(ballu.START_LEVEL_NAMES)}, a "
                                         f"level or LOW:HIGH with 0 <= LOW <= HIGH <= {ballu.MAX_LEVEL}")
    return lv if sep else lv[0]


def _parser():
    ap = args.program("python -m experiments.ppo_ballu", __doc__)
    sub = ap.add_subparsers(dest="mode", required=True)
    tr = args.command(sub, "train", "train one policy (resumes OUT/policy.pt)", __doc__)
    tr.add_argument("--out", required=True, metavar="OUT", help="the policy's folder")
    tr.add_argument("--kind", default="mlp", choices=tuple(ppo.POLICIES))
    tr.add_argument("--steps", type=int, default=1_000_000, help="control steps (>= 1)")
    tr.add_argument("--envs", type=int, default=ppo.PPOConfig.num_envs, help="lanes in all (>= 1)")
    tr.add_argument("--rollout", type=int, default=ppo.PPOConfig.num_steps, help="steps per env and update")
    tr.add_argument("--seed", type=int, default=0)
    tr.add_argument("--start-level", type=start_levels, default="task",
                    help="curriculum start: 'task' (ballu.train_start_levels), 'spread', 'zero', L or LOW:HIGH")
    tr.add_argument("--reward", default="paper", choices=("paper", "code"))
    tr.add_argument("--init-mean", type=float, default=0.5, help="initial mean action (0.5 = servo half way)")
    tr.add_argument("--entropy", type=float, default=ppo.PPOConfig.entropy_coef, help="entropy bonus (>= 0)")
    tr.add_argument("--score", action="store_true", help="score the trained policy (J, 20 episodes)")
    st = args.command(sub, "strip", "a motion strip (PNG) of one episode of a trained policy", __doc__)
    st.add_argument("--out", required=True, metavar="PNG", help="the PNG to write")
    st.add_argument("--policy", metavar="CKPT", required=True, help="a checkpoint of ppo.py")
    st.add_argument("--level", type=int, default=30, help=f"terrain level, 0..{ballu.MAX_LEVEL}")
    for p in (tr, st):
        p.add_argument("--task", default="obstacle", choices=ballu.TASKS)
        p.add_argument("--design", default="baseline", help=DESIGN_HELP + "; default baseline")
        args.add_workers(p, "worker processes, 1..--envs")
    return ap


def _check_train(ap, a):
    checks = (("--steps", a.steps, ">= 1", a.steps >= 1),
              ("--envs", a.envs, ">= 1", a.envs >= 1),
              ("--rollout", a.rollout, ">= 1", a.rollout >= 1),
              ("--workers", a.workers, f"in [1, --envs {a.envs}]", 1 <= a.workers <= a.envs),
              ("--seed", a.seed, "in [0, 2**64 - 1]", 0 <= a.seed < 2 ** 64),
              ("--entropy", a.entropy, "finite and >= 0", 0 <= a.entropy < math.inf),
              ("--init-mean", a.init_mean, "finite", abs(a.init_mean) < math.inf))   # NaN fails them all
    for opt, value, rule, ok in checks:
        if not ok:
            ap.error(f"{opt} {value} must be {rule}")


def train(a, sampler):
    cfg = ppo.PPOConfig(num_envs=a.envs, num_steps=a.rollout, init_action_mean=a.init_mean,
                        entropy_coef=a.entropy)
    os.makedirs(a.out, exist_ok=True)
    env = ballu.make_env(cfg.num_envs, a.workers, ballu.BalluConfig(task=a.task, reward_form=a.reward))
    ck = os.path.join(a.out, "policy.pt")
    try:
        out = ppo.train(a.kind, env, sampler, a.steps, ck, cfg, seed=a.seed,
                        start_level=ballu.named_start_levels(a.start_level, a.task),
                        log_csv=os.path.join(a.out, "log.csv"))
    finally:
        env.close()
    ppo.plot_learning_curve(os.path.join(a.out, "log.csv"), os.path.join(a.out, "curve.png"),
                            f"{a.kind} {a.task} {a.design}")
    print("trained:", out)
    if a.score:
        designs = sampler(np.random.default_rng(123), 8 if a.design == "d2" else 1)
        s = ballu.score(ppo.load_policy(ck), designs, a.task, workers=a.workers)
        print(f"J = {s.round(2).tolist()} (mean {s.mean():.2f})")


def main(argv=None):
    ap = _parser()
    a = args.parse(ap, argv)
    try:
        sampler = design_sampler(a.design)
    except args.BadArg as e:
        ap.error(str(e))
    if a.mode == "train":
        _check_train(ap, a)
        return train(a, sampler)
    if not 0 <= a.level <= ballu.MAX_LEVEL:
        ap.error(f"--level {a.level} must lie in [0, {ballu.MAX_LEVEL}]")
    try:
        policy = ppo.load_policy(a.policy)
    except (OSError, ValueError) as e:
        ap.error(f"--policy: {e}")
    design = sampler(np.random.default_rng(0), 1)[0]
    try:
        print("wrote", motion_strip(a.out, policy, a.task, a.level, design))
    except OSError as e:
        ap.error(f"--out {a.out!r} cannot be written: {e.strerror}")


if __name__ == "__main__":
    sys.exit(main())
