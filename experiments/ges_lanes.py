"""experiments/ges_lanes.py -- does a GES specialist learn anything in its rounds? Lane layouts, screened.

A specialist round trains `ges_round_steps` PPO steps in a fresh env (policies.TrainSpecialist): with the quick
preset's 10k steps on 32 lanes a lane runs 312 steps per round, less than one 400-step episode, so no episode
ends, the curriculum never moves and PPO sees only episodes' beginnings. This study fine-tunes the e2e MLP on
each final territory of a finished run_all GES run, round by round exactly as GES does (same round steps and
rounds, same trainer), under each lane layout (lanes x rollout, the same batch), then scores the routed
specialists on the run's test designs, paired with the run's e2e MLP on the same designs. A layout with a
'u' (e.g. 32x64u) is the control: the same rounds on uniform designs over the whole space, the e2e MLP's own
training distribution, so what it changes is what any further PPO steps change, not specialisation. A layout
with an 's' (e.g. 32x64s) trains the specialists from random init, as the paper's Alg. 1 does. `--rounds` and
`--round-steps` replace the run's rounds and the preset's steps per round (e.g. 10 x 30k).

    python -m experiments.ges_lanes RUN --task obstacle --space d2 --layouts 32x64,8x256,32x64u --seeds 0,1 --out DIR
    python -m experiments.ges_lanes RUN --layouts 32x64,32x64u,32x64s --rounds 10 --round-steps 30000 --out DIR

RUN: a finished `run_all.py` output folder (its preset given by --preset). Results: docs/ges_lanes/. [ours]
"""
from __future__ import annotations

import json
import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace

import numpy as np

import ballu
import ges
import ppo
from codesign import policies
import run_all
from experiments import args
from runkit.stats import paired_comparison


def layouts(text: str) -> list:
    """'32x64,8x256u,32x64s' -> [(32, 64, ''), (8, 256, 'u'), (32, 64, 's')]: lanes x rollout steps per update,
    and the variant: '' territories from the e2e MLP, 'u' uniform designs (control), 's' from scratch."""
    out = []
    for part in text.lower().split(","):
        variant = part[-1] if part[-1:] in ("u", "s") else ""
        try:
            n, t = (int(v) for v in part.rstrip("us").split("x"))
        except ValueError:
            raise ValueError(f"--layouts: {part!r} is not LANESxROLLOUT[u|s], e.g. 32x64 or 32x64u") from None
        if n < 1 or t < 1:
            raise ValueError(f"--layouts: {part!r} needs lanes >= 1 and rollout >= 1")
        out.append((n, t, variant))
    return out


@dataclass(eq=False)
class Uniform:
    """The control's sampler: uniform designs over the whole box (a GaussianSampler's interface)."""
    space: ges.Box
    seed: int = 0

    def __call__(self, rng: np.random.Generator, n: int) -> np.ndarray:
        return self.space.sample_uniform(rng, n)


def specialist(task, sp, preset, mlp_ckpt, mu, sigma, box, k, seed, rounds, folder, uniform=False) -> str:
    """Specialist k from `mlp_ckpt` ('': random init): `rounds` rounds on N(mu, sigma) (or uniform), as ges_round
    calls it."""
    trainer = policies.TrainSpecialist(task, policies.space_of(preset, task, sp), preset.ges_round_steps, preset,
                                      mlp_ckpt)
    ckpt_in = None
    for r in range(rounds):
        out = os.path.join(folder, os.path.basename(ges.ckpt_path(k, r)))
        if not os.path.exists(out):
            s = ges.seed_for(seed, 1, r, k)
            trainer(k, r, Uniform(box, s) if uniform else ges.GaussianSampler(mu, sigma, box, s), ckpt_in, out)
        ckpt_in = out
    return ckpt_in


def level_moves(folder: str, K: int, rounds: int) -> float:
    """Mean curriculum level at the end of the last round minus at the start of the first, over specialists."""
    moves = []
    for k in range(K):
        first = np.genfromtxt(os.path.join(folder, f"spec{k}_round00.ckpt.csv"), delimiter=",", names=True)
        last = np.genfromtxt(os.path.join(folder, f"spec{k}_round{rounds - 1:02d}.ckpt.csv"), delimiter=",",
                             names=True)
        moves.append(float(np.atleast_1d(last["mean_level"])[-1] - np.atleast_1d(first["mean_level"])[0]))
    return float(np.mean(moves))


def one(run_dir, task, sp, preset, lanes, rollout, variant, seed, out, rounds=None, workers=2) -> dict:
    """Train the K specialists of one layout and seed (`workers` at a time), score them routed on the test designs.
    `rounds`: None = the run's; a preset whose ges_round_steps differs from the run's names its own folder."""
    tag = f"{lanes}x{rollout}{variant}_seed{seed}"
    if rounds is not None or preset.ges_round_steps != run_all.PRESETS[preset.name].ges_round_steps:
        tag += f"_r{rounds or 'run'}x{preset.ges_round_steps}"
    folder = os.path.join(out, f"{task}-{sp}", tag)
    done = os.path.join(folder, "result.json")
    if os.path.exists(done):
        return json.load(open(done))
    os.makedirs(folder, exist_ok=True)
    K = preset.K_d2 if sp == "d2" else preset.K_d3
    result = ges.load_result(os.path.join(run_dir, "ges", f"{task}-{sp}-K{K}-fps-lloyd"))
    p = replace(preset, ppo_envs=lanes, ppo_rollout=rollout)
    mlp = "" if variant == "s" else ppo.scored_path(os.path.join(run_dir, "policies", f"mlp-{task}-{sp}", "policy.pt"),
                                                    preset.policy_rule)
    rounds = result.rounds if rounds is None else rounds
    t0 = time.time()
    with ProcessPoolExecutor(workers) as ex:
        ckpts = list(ex.map(specialist, *zip(*[(task, sp, p, mlp, result.mu_unit[k], result.sigma_unit[k],
                                                result.space, k, seed, rounds, folder, variant == "u")
                                               for k in range(K)])))
    train_s = time.time() - t0
    space = policies.space_of(preset, task, sp)
    designs = run_all.Run(run_dir, preset, 0, 1).test_designs(task, sp)
    routed, J = result.route(designs), np.empty(len(designs))
    for k in np.unique(routed):
        J[routed == k] = policies.score_policy(ppo.load_policy(ppo.scored_path(ckpts[k], preset.policy_rule)),
                                              space.full(designs[routed == k]), task, preset, workers)
    res = {"layout": [lanes, rollout], "uniform": variant == "u", "scratch": variant == "s", "seed": seed,
           "rounds": rounds, "round_steps": preset.ges_round_steps, "J": J.tolist(), "routed": routed.tolist(),
           "level_move": level_moves(folder, K, rounds), "train_s": train_s}
    json.dump(res, open(done, "w"))
    return res


def paired(a, b) -> str:
    """run_all's paired comparison of a and b on the same designs, as a table cell."""
    c = paired_comparison(a, b)
    return f"{c['diff']:+.1f} [{c['diff_lo']:+.1f}, {c['diff_hi']:+.1f}], p={c['p']:.2g}"


def main(argv=None):
    ap = args.program("python -m experiments.ges_lanes", __doc__)
    ap.add_argument("run", help="a finished run_all.py output folder")
    ap.add_argument("--preset", default="quick", choices=tuple(run_all.PRESETS))
    ap.add_argument("--task", default="obstacle", choices=("obstacle", "ramp"))
    ap.add_argument("--space", default="d2", choices=("d2", "d3"))
    ap.add_argument("--layouts", default="32x64,8x256", help="lanes x rollout per update, comma separated")
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--rounds", type=int, default=None, help="rounds per specialist (default: the run's)")
    ap.add_argument("--round-steps", type=int, default=None, help="PPO steps per round (default: the preset's)")
    ap.add_argument("--out", required=True, metavar="DIR", help="the study's folder (resumed: each layout and seed "
                    "keeps its result.json)")
    args.add_workers(ap)
    a = args.parse(ap, argv)
    for name in ("rounds", "round_steps", "workers"):
        if getattr(a, name) is not None and getattr(a, name) < 1:
            ap.error(f"--{name.replace('_', '-')}={getattr(a, name)} must be >= 1")
    preset, task, sp = run_all.PRESETS[a.preset], a.task, a.space
    if a.round_steps:
        preset = replace(preset, ges_round_steps=a.round_steps)
    seeds = [int(s) for s in a.seeds.split(",")]
    scores = lambda m: json.load(open(os.path.join(a.run, "scores", f"test-{task}-{sp}-{m}.json")))["scores"]
    K = preset.K_d2 if sp == "d2" else preset.K_d3
    mlp, ges_run = scores("mlp"), scores(f"ges-{task}-{sp}-K{K}-fps-lloyd")
    n_rounds = a.rounds or "the run's"
    budget = f", {n_rounds} rounds x {preset.ges_round_steps:,} steps" if a.rounds or a.round_steps else ""
    rows = [f"# GES specialists by lane layout: {task} {sp}, run {a.run} (preset {a.preset}){budget}", "",
            f"e2e MLP {np.mean(mlp):.2f}; the run's GES {np.mean(ges_run):.2f} (paired {paired(ges_run, mlp)})", "",
            "| layout (lanes x rollout) | seed | GES J | GES - e2e MLP [95 % paired CI], Wilcoxon p | level move | "
            "train s |", "|---|---|---|---|---|---|"]
    per_layout = {}
    for lanes, rollout, variant in layouts(a.layouts):
        name = f"{lanes}x{rollout}" + {"": "", "u": " uniform (control)", "s": " from scratch"}[variant]
        for s in seeds:
            r = one(a.run, task, sp, preset, lanes, rollout, variant, s, a.out, a.rounds, a.workers)
            per_layout.setdefault(name, []).append(np.mean(r["J"]) - np.mean(mlp))
            rows.append(f"| {name} | {s} | {np.mean(r['J']):.2f} | {paired(r['J'], mlp)} | "
                        f"{r['level_move']:+.2f} | {r['train_s']:.0f} |")
            print(rows[-1], flush=True)
    rows += ["", "| layout | GES - e2e MLP, mean +- SE over seeds |", "|---|---|"]
    rows += [f"| {n} | {np.mean(v):+.2f} +- {np.std(v, ddof=1) / np.sqrt(len(v)) if len(v) > 1 else 0:.2f} |"
             for n, v in per_layout.items()]
    text = "\n".join(rows) + "\n"
    suffix = f"-r{a.rounds or 'run'}x{preset.ges_round_steps}" if a.rounds or a.round_steps else ""
    open(os.path.join(a.out, f"{task}-{sp}{suffix}.md"), "w").write(text)
    print(text)


if __name__ == "__main__":
    main()
