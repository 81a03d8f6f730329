"""experiments/ppo_ballu.py -- train one PPO policy on BALLU, or film one, from the command line.

    python -m experiments.ppo_ballu train OUT --task obstacle --design baseline --steps 1000000 [--score]
    python -m experiments.ppo_ballu strip PNG --policy OUT/policy.pt --task obstacle --level 16

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
from report.strip import motion_strip

NAMED_DESIGNS = {"baseline": ballu.BASELINE, "d2c": ballu.D2_CENTRE}


def design_sampler(text: str):
    """--design: baseline | d2c (the centre of D2) | d2 (uniform over D2) | l_f,l_t,gcr,spcf; a ValueError
    naming what is wrong otherwise."""
    if text in NAMED_DESIGNS:
        return ballu.FixedDesign(NAMED_DESIGNS[text])
    if text == "d2":
        return ballu.UniformDesign(ballu.d2())
    return ballu.FixedDesign(parse_design(text, "baseline, d2c, d2 or "))


def parse_design(text: str, others: str = "") -> np.ndarray:
    """--design l_f,l_t,gcr,spcf as a checked design (4,); a ValueError naming what is wrong otherwise."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 4:
        raise ValueError(f"--design {text!r} must be {others}four numbers l_f,l_t,gcr,spcf")
    return ballu.check_design(values, what="--design")[0]


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
    ap = argparse.ArgumentParser(prog="python -m experiments.ppo_ballu", description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="mode", required=True)
    tr = sub.add_parser("train", help="train one policy (resumes OUT/policy.pt)")
    tr.add_argument("out", metavar="OUT_DIR")
    tr.add_argument("--kind", default="mlp", choices=tuple(ppo.POLICIES))
    tr.add_argument("--steps", type=int, default=1_000_000, help="control steps (>= 1)")
    tr.add_argument("--envs", type=int, default=ppo.PPOConfig.num_envs, help="parallel envs (>= 1)")
    tr.add_argument("--rollout", type=int, default=ppo.PPOConfig.num_steps, help="steps per env and update")
    tr.add_argument("--seed", type=int, default=0)
    tr.add_argument("--start-level", type=start_levels, default="task",
                    help="curriculum start: 'task' (ballu.train_start_levels), 'spread', 'zero', L or LOW:HIGH")
    tr.add_argument("--reward", default="paper", choices=("paper", "code"))
    tr.add_argument("--init-mean", type=float, default=0.5, help="initial mean action (0.5 = servo half way)")
    tr.add_argument("--entropy", type=float, default=ppo.PPOConfig.entropy_coef, help="entropy bonus (>= 0)")
    tr.add_argument("--score", action="store_true", help="score the trained policy (J, 20 episodes)")
    st = sub.add_parser("strip", help="a motion strip (PNG) of one episode of a trained policy")
    st.add_argument("png", metavar="PNG")
    st.add_argument("--policy", metavar="CKPT", required=True, help="a checkpoint of ppo.py")
    st.add_argument("--level", type=int, default=30, help=f"terrain level, 0..{ballu.MAX_LEVEL}")
    for p in (tr, st):
        p.add_argument("--task", default="obstacle", choices=ballu.TASKS)
        p.add_argument("--design", default="baseline", help="baseline | d2c | d2 (uniform) | l_f,l_t,gcr,spcf")
        p.add_argument("--workers", type=int, default=2, help="worker processes (1..--envs)")
    return ap


def _check_train(ap, args):
    checks = (("--steps", args.steps, ">= 1", args.steps >= 1),
              ("--envs", args.envs, ">= 1", args.envs >= 1),
              ("--rollout", args.rollout, ">= 1", args.rollout >= 1),
              ("--workers", args.workers, f"in [1, --envs {args.envs}]", 1 <= args.workers <= args.envs),
              ("--seed", args.seed, "in [0, 2**64 - 1]", 0 <= args.seed < 2 ** 64),
              ("--entropy", args.entropy, "finite and >= 0", 0 <= args.entropy < math.inf),
              ("--init-mean", args.init_mean, "finite", abs(args.init_mean) < math.inf))   # NaN fails them all
    for opt, value, rule, ok in checks:
        if not ok:
            ap.error(f"{opt} {value} must be {rule}")


def train(args, sampler):
    cfg = ppo.PPOConfig(num_envs=args.envs, num_steps=args.rollout, init_action_mean=args.init_mean,
                        entropy_coef=args.entropy)
    os.makedirs(args.out, exist_ok=True)
    env = ballu.make_env(cfg.num_envs, args.workers, ballu.BalluConfig(task=args.task, reward_form=args.reward))
    ck = os.path.join(args.out, "policy.pt")
    try:
        out = ppo.train(args.kind, env, sampler, args.steps, ck, cfg, seed=args.seed,
                        start_level=ballu.named_start_levels(args.start_level, args.task),
                        log_csv=os.path.join(args.out, "log.csv"))
    finally:
        env.close()
    ppo.plot_learning_curve(os.path.join(args.out, "log.csv"), os.path.join(args.out, "curve.png"),
                            f"{args.kind} {args.task} {args.design}")
    print("trained:", out)
    if args.score:
        designs = sampler(np.random.default_rng(123), 8 if args.design == "d2" else 1)
        s = ballu.score(ppo.load_policy(ck), designs, args.task, workers=args.workers)
        print(f"J = {s.round(2).tolist()} (mean {s.mean():.2f})")


def main(argv=None):
    ap = _parser()
    args = ap.parse_args(argv)
    try:
        sampler = design_sampler(args.design)
    except ValueError as e:
        ap.error(str(e))
    if args.mode == "train":
        _check_train(ap, args)
        return train(args, sampler)
    if not 0 <= args.level <= ballu.MAX_LEVEL:
        ap.error(f"--level {args.level} must lie in [0, {ballu.MAX_LEVEL}]")
    try:
        policy = ppo.load_policy(args.policy)
    except (OSError, ValueError) as e:
        ap.error(f"--policy: {e}")
    design = sampler(np.random.default_rng(0), 1)[0]
    try:
        print("wrote", motion_strip(args.png, policy, args.task, args.level, design))
    except OSError as e:
        ap.error(f"PNG {args.png!r} cannot be written: {e.strerror}")


if __name__ == "__main__":
    sys.exit(main())
