"""experiments/probe_agreement.py -- may GES probe with a cheaper score than the paper's J? (docs/probe_agreement)

    python -m experiments.probe_agreement A.pt,B.pt [--task obstacle] [--designs 20] [--level-steps 16,8,...]
                                          [--episodes 20] [--jitter 0.001] [--workers N] [--seed S]

Scores uniform D2 designs with each checkpoint by the full J and by a probe schedule (`ballu.score`'s
`level_steps`) and prints the share of designs where both pick the same winner, the rank correlation and both
wall times, against PROBE_BAR.
"""
from __future__ import annotations

import os
import sys
import time

import numpy as np
from scipy.stats import spearmanr

import ballu
import ppo
from experiments import args
from codesign.policies import derive_seed
from run_all import TASKS, read_back, say
from runkit.files import BadInput

# [ours] a bisection over curriculum levels for GES's probe scores (ballu.score's `level_steps`), ~3x cheaper
# than the 20-episode J; in no preset: it picks J's winner too rarely (docs/probe_agreement).
BISECTION = (16, 8, 4, 2, 1, 1, 1)
PROBE_BAR = {"same_winner_pct": 80.0, "spearman": 0.9}   # [ours] the bar for using a cheaper probe score in GES


def probe_winners(J: np.ndarray) -> np.ndarray:
    """Per design (column), the checkpoint (row) GES's probe argmax picks: the highest J, ties -> the lowest
    index, as ges.ges_round does (facts). Agreement is measured on what decides the territories."""
    return np.argmax(J, axis=0)


def probe_agreement(ckpts: list, task: str = "obstacle", n_designs: int = 20, level_steps=BISECTION,
                    episodes: int = ballu.SCORE_EPISODES, seed: int = 0, workers: int = 1, jitter: float = 0.0,
                    progress=say) -> dict:
    """Does a probe schedule rank like the paper's J? Scores `n_designs` uniform D2 designs with each of the K
    checkpoints both ways, the full J (`episodes` unit steps) and the probe J (`level_steps`), and returns the
    share of designs where both pick the same winner (probe_winners' tie rule; the share of designs with a tie
    is returned too, since ties inflate agreement), Spearman's rank correlation over all K x n (design,
    checkpoint) pairs (NaN if one way scored every pair alike) and each way's wall time.

    `jitter` > 0 adds a third way, the ceiling of the bar [ours]: the full J itself on designs moved by
    +-jitter of each axis' range (random signs). No probe score can agree with J better than J agrees with
    itself a hair's breadth away, so its same-winner share and rank correlation say whether the bar can be met
    on these checkpoints at all."""
    space = ballu.d2(task)   # Table I bounds
    rng = np.random.default_rng(derive_seed(seed, "probe-agreement", task))
    theta = space.sample_uniform(rng, n_designs)
    ways = {"full": (theta, {"episodes": episodes}), "probe": (theta, {"level_steps": tuple(level_steps)})}
    if jitter > 0:
        span = np.asarray(space.highs) - np.asarray(space.lows)
        moved = np.clip(theta + jitter * span * rng.choice([-1.0, 1.0], theta.shape), space.lows, space.highs)
        ways["jitter"] = (moved, {"episodes": episodes})
    J = {w: np.zeros((len(ckpts), n_designs)) for w in ways}
    seconds = {w: 0.0 for w in ways}
    for k, ckpt in enumerate(ckpts):
        policy = read_back(ckpt, ppo.load_policy, "ppo.py checkpoint", "give checkpoints that ppo.py wrote")
        for w, (th, kw) in ways.items():
            t0 = time.time()
            J[w][k] = ballu.score(policy, space.full(th), task, workers=max(1, min(workers, n_designs)), **kw)
            seconds[w] += time.time() - t0
            progress(f"probe agreement: checkpoint {k + 1}/{len(ckpts)} {w} J done ({seconds[w]:.0f} s so far)")
    win = {w: probe_winners(J[w]) for w in ways}

    def agreement(w):   # (same winner %, Spearman) of way w against the full J
        constant = np.ptp(J["full"]) == 0 or np.ptp(J[w]) == 0
        rho = float("nan") if constant else float(spearmanr(J["full"].ravel(), J[w].ravel())[0])
        return float(100 * np.mean(win["full"] == win[w])), rho

    out = {"task": task, "designs": space.full(theta).tolist(), "ckpts": list(ckpts), "episodes": episodes,
           "level_steps": list(level_steps), "J_full": J["full"].tolist(), "J_probe": J["probe"].tolist(),
           "tie_pct": {w: float(100 * np.mean((J[w] == J[w].max(axis=0)).sum(axis=0) > 1)) for w in ways},
           "seconds": seconds}
    out["same_winner_pct"], out["spearman"] = agreement("probe")
    if jitter > 0:
        out.update(jitter=jitter, J_jitter=J["jitter"].tolist(), ceiling=dict(zip(("same_winner_pct", "spearman"),
                                                                               agreement("jitter"))))
    return out


def probe_agreement_text(r: dict) -> str:
    """The measurement in a few lines, against PROBE_BAR."""
    K, n = len(r["ckpts"]), len(r["designs"])
    ok = r["same_winner_pct"] >= PROBE_BAR["same_winner_pct"] and r["spearman"] >= PROBE_BAR["spearman"]
    full_s, probe_s = r["seconds"]["full"], r["seconds"]["probe"]
    return "\n".join([
        f"probe agreement, {r['task']}: {n} uniform D2 designs x {K} checkpoints; full J = {r['episodes']} unit "
        f"steps, probe J = level steps {r['level_steps']}",
        f"  same winner (highest J, ties -> lowest index as GES's probe argmax): {r['same_winner_pct']:.1f} % "
        f"(bar >= {PROBE_BAR['same_winner_pct']:.0f} %); designs with a tie: full {r['tie_pct']['full']:.1f} %, "
        f"probe {r['tie_pct']['probe']:.1f} %",
        f"  Spearman rank correlation over all {K * n} (design, checkpoint) pairs: "
        + (f"{r['spearman']:.3f}" if np.isfinite(r["spearman"]) else "undefined (one way scored every pair alike)")
        + f" (bar >= {PROBE_BAR['spearman']})",
        f"  wall time: full J {full_s:.0f} s, probe J {probe_s:.0f} s ({full_s / max(probe_s, 1e-9):.1f}x faster)",
        f"  the bar (PROBE_BAR): {'met' if ok else 'NOT met'}"]
        + ([f"  ceiling: the full J on designs moved by +-{100 * r['jitter']:g} % of each range agrees with the "
            f"full J on {r['ceiling']['same_winner_pct']:.1f} % of winners, Spearman {r['ceiling']['spearman']:.3f}"]
           if "ceiling" in r else []))


def check_args(a) -> dict:
    """The command line's arguments as probe_agreement's keywords; BadInput names what is wrong."""
    ckpts = [c for c in a.ckpts.split(",") if c]
    missing = [c for c in ckpts if not os.path.isfile(c)]
    if len(ckpts) < 2 or missing:
        raise BadInput(f"CKPT,CKPT,... needs >= 2 existing checkpoints, comma-separated; got {len(ckpts)}"
                       + (f", missing: {missing}" if missing else ""))
    if a.task not in TASKS:
        raise BadInput(f"--task {a.task} must be one of {TASKS}")
    if min(a.designs, a.workers, a.episodes) < 1 or a.seed < 0:
        raise BadInput(f"--designs {a.designs}, --workers {a.workers}, --episodes {a.episodes} must be "
                       f">= 1 and --seed {a.seed} >= 0")
    try:
        steps = tuple(ballu.check_level_steps(tuple(int(s) for s in a.level_steps.split(",")), None).tolist())
    except ValueError:
        raise BadInput(f"--level-steps {a.level_steps} must be comma-separated integers in "
                       f"[1, {ballu.MAX_LEVEL}]") from None
    if not 0 <= a.jitter < 1:
        raise BadInput(f"--jitter {a.jitter} must lie in [0, 1) (a share of each design axis' range)")
    return {"ckpts": ckpts, "task": a.task, "n_designs": a.designs, "level_steps": steps,
            "episodes": a.episodes, "seed": a.seed, "workers": a.workers, "jitter": a.jitter}


def main(argv=None) -> int:
    ap = args.program("python -m experiments.probe_agreement", __doc__)
    ap.add_argument("ckpts", metavar="CKPT,CKPT,...", help="ppo.py checkpoints, comma-separated (>= 2)")
    ap.add_argument("--task", default="obstacle", help="obstacle or ramp")
    ap.add_argument("--designs", type=int, default=20, metavar="N", help="uniform D2 designs (default 20)")
    ap.add_argument("--level-steps", default=",".join(map(str, BISECTION)),
                    help=f"the probe schedule (default {','.join(map(str, BISECTION))})")
    ap.add_argument("--episodes", type=int, default=ballu.SCORE_EPISODES,
                    help=f"episodes of the full J (default {ballu.SCORE_EPISODES})")
    ap.add_argument("--jitter", type=float, default=0.0, help="also score the full J on designs moved by this "
                    "share of each range (e.g. 0.001), the ceiling any probe score can reach")
    args.add_workers(ap, "processes")
    ap.add_argument("--seed", type=int, default=0)
    a = args.parse(ap, argv)
    try:
        print(probe_agreement_text(probe_agreement(**check_args(a))), flush=True)
    except BadInput as e:
        print(f"{ap.prog}: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
