"""codesign/policies.py -- a run's policies: how run_all trains one, scores one, and makes GES's callables.

The co-design of BALLU (paper Sec. IV) joins three modules that know nothing of each other: ppo.py trains a
policy on any batched env, ballu.py plays a design, ges.py takes a trainer and a scorer as plain callables. This
module is the glue, one home per idea:
  1. the design spaces (D2, D3) and a training job: `train_policy` (skip / resume / restart, bit-identical)
  2. J on full designs: `score_policy` (the run's episodes, GES's probe schedule, every episode's final x)
  3. GES's callables (ges.py's contract): `TrainSpecialist` (train_fn), `ScoreSpecialist` (score_fn)
  4. J(theta) of each method: `PolicyJ` (one policy), `ges_J` (the router, eq. 10), `method_J`; per-design BO's
     objective (`PerDesignBO`, the cost baseline of Sec. V-D)
  5. a GES run's files read back, seeds, the --rates job
A `preset` is run_all.Preset and a `run` run_all.Run (read by attribute: this module imports no run_all).
"""
from __future__ import annotations

import hashlib
import os
import time
import zlib
from dataclasses import dataclass, replace

import numpy as np

import ballu
import ges
import ppo
from runkit.files import FRESH, READ_ERRORS, read_back, read_json, redo_if_damaged, write_json
from runkit.logs import train_seconds, trim_log
from runkit.plan import job_rates
from runkit.progress import Throttled


# ----------------------------------------------------------------------------------------------------------
# 1. The design spaces and a training job
# ----------------------------------------------------------------------------------------------------------
def space_of(preset: Preset, task: str, sp: str) -> ballu.DesignSpace:
    """D2 = (GCR, SPCF) on one robot; D3 = (GCR, SPCF, l) with l_f = l_t = l (paper Sec. III-B); the box and D2's
    robot are the preset's setup's (ballu.SETUPS)."""
    return (ballu.d2 if sp == "d2" else ballu.d3)(task, preset.setup)


def ppo_config(preset: Preset) -> ppo.PPOConfig:
    return ppo.PPOConfig(num_envs=preset.ppo_envs, num_steps=preset.ppo_rollout,
                         init_action_mean=preset.ppo_init_action_mean)


def start_levels(task: str, preset: Preset):
    """A fresh training run's curriculum start (a warm start keeps its checkpoint's levels): Preset.ppo_start."""
    return ballu.named_start_levels(preset.ppo_start, task, preset.score_start_level)


def train_policy(ckpt: str, kind: str, task: str, sampler, steps: int, preset: Preset, seed: int, label: str = "",
                 init_ckpt: str | None = None, log: str | None = None) -> str:
    """Train one PPO policy into `ckpt` to `steps` control steps, in-process on one core, its learning curve in
    `log` (default: log.csv beside it), warm-started from `init_ckpt` if given; `label` prefixes its progress
    lines ("": silent). The one home of a training job's skip / resume / restart: a checkpoint at its steps is
    kept (done in an earlier attempt); one killed mid-way goes on from its last checkpoint, its lanes' episodes
    replayed, so it ends bit-identical with an uninterrupted run (its log trimmed to the checkpoint); one that
    cannot go on exactly (damaged: moved aside by redo_if_damaged; or without lanes' state: a finished shorter
    run's, an older code's) is deleted with its best policy and log, and the job trains from scratch."""
    os.makedirs(os.path.dirname(ckpt) or ".", exist_ok=True)
    log = log or os.path.join(os.path.dirname(ckpt), "log.csv")
    own = redo_if_damaged(ckpt, ppo.load_checkpoint, "ppo.py checkpoint", f"retraining {label or ckpt}")
    if own and own["steps"] >= steps:
        return ckpt
    if own and "run" in own:
        trim_log(log, own["steps"])
    else:
        for f in (ckpt, ppo.best_path(ckpt), log):
            if os.path.exists(f):
                os.remove(f)
    cfg = ppo_config(preset)
    env = ballu.make_env(cfg.num_envs, 1, preset.env_config(ballu.BalluConfig(task=task)))
    try:
        ppo.train(kind, env, sampler, steps, ckpt, cfg, init_ckpt=init_ckpt, seed=seed,
                  start_level=start_levels(task, preset), log_csv=log, progress=Throttled(label) if label else None)
    finally:
        env.close()
    return ckpt


# ----------------------------------------------------------------------------------------------------------
# 2. J on full designs
# ----------------------------------------------------------------------------------------------------------
def score_policy(policy, designs_full, task, preset: Preset, workers: int = 1, label: str = "",
                 probe: bool = False, trace: dict | None = None, stats: dict | None = None) -> np.ndarray:
    """J on a batch of full designs, spread over the shared worker pool (results do not depend on the worker
    count or on the call's other designs: ballu.score gives each design a PyBullet world of its own, and learned
    policies run row by row).

    The one home of how a run scores: the preset's episodes from its start level (the task's, or smoke's
    `score_start_level`); probe=True: GES's probe score, the preset's `probe_level_steps` schedule if it has
    one (tables and test designs keep the paper's J). `trace` (a dict) receives each design's per-episode
    final pelvis x (None for a blown-up episode) under its full design's bytes: score sets store trajectories,
    not only levels, so runs that should be equal are compared on more than a few coarse levels."""
    steps = preset.probe_level_steps if probe else None
    j, x = ballu.score(policy, designs_full, task, episodes=None if steps else preset.score_episodes,
                       start_level=preset.score_start_level, level_steps=steps,
                       cfg=preset.env_config(ballu.policy_config(policy, task)),
                       workers=max(1, min(workers, len(designs_full))), progress=Throttled(label) if label else None,
                       final_x=True, stats=stats, strict=preset.score_rule(task))
    if trace is not None:
        trace.update({np.asarray(d, float).tobytes(): [float(v) if np.isfinite(v) else None for v in row]
                      for d, row in zip(designs_full, x)})
    return j


def tiebreak(full, trace: dict) -> np.ndarray:
    """Preset.probe_tiebreak [ours]: 1e-3 x each design's mean final pelvis x over its episodes (m, clipped to
    +-10; a blown-up episode counts -10): < 0.011, below the least step between two levels' J (0.4 deg), so it
    orders only probes the specialists tie on, by how far they went."""
    xs = [[-10.0 if x is None else x for x in trace[d.tobytes()]] for d in np.asarray(full, float)]
    return 1e-3 * np.clip([np.mean(x) for x in xs], -10, 10)


# ----------------------------------------------------------------------------------------------------------
# 3. GES's callables (ges.py's contract: train_fn, score_fn)
# ----------------------------------------------------------------------------------------------------------
@dataclass
class TrainSpecialist:
    """GES train_fn (ges.py contract): PPO on designs from the specialist's Gaussian, one process each.

    Round r warm-starts from the specialist's round r-1 checkpoint (policy, optimiser, normaliser, curriculum
    and step count carry over) and trains to Preset.ges_steps(r + 1) control steps at this trainer's round sizes,
    on top of the warm-start policy's steps. A repeated (interrupted) round skips, resumes or retrains each
    specialist as train_policy does, so the round is identical to an uninterrupted one."""
    task: str
    space: ballu.DesignSpace
    round_steps: int
    preset: Preset
    warm_ckpt: str = ""   # Preset.ges_warm_start: round 0 starts from this policy (the cell's e2e MLP)
    first_round_steps: int | None = None   # round 0's steps (None: round_steps); Preset.ges_first_round_steps
    label: str = ""   # progress lines' prefix (the GES run's name); "" trains silently

    def __call__(self, k, round, sampler, ckpt_in, ckpt_out):
        base = read_back(self.warm_ckpt, ckpt_steps, "ppo.py checkpoint") if self.warm_ckpt else 0
        sizes = replace(self.preset, ges_round_steps=self.round_steps, ges_first_round_steps=self.first_round_steps)
        train_policy(ckpt_out, "mlp", self.task, ballu.InSpace(self.space, sampler), base + sizes.ges_steps(round + 1),
                     self.preset, sampler.seed, f"{self.label} specialist {k} round {round}" if self.label else "",
                     ckpt_in or self.warm_ckpt or None, ckpt_out + ".csv")


@dataclass
class ScoreSpecialist:
    """GES score_fn (ges.py contract): J of specialist k's deterministic policy on each design (one lane each).
    GES's probes (probe=True) may use the preset's cheaper schedule; the router's J (test designs, TPE) is the
    paper's. Inside GES's rounds the specialists are scored side by side, one process each (workers=1)."""
    task: str
    space: ballu.DesignSpace
    preset: Preset
    workers: int = 1
    label: str = ""
    probe: bool = False
    trace: dict | None = None   # see score_policy (in-process callers only)

    def __call__(self, k, ckpt, designs):
        full, tie = self.space.full(designs), self.probe and self.preset.probe_tiebreak
        trace = {} if tie and self.trace is None else self.trace
        j = score_policy(load_ges_ckpt(ckpt, self.preset), full, self.task, self.preset, self.workers,
                         f"{self.label} specialist {k}" if self.label else "", self.probe, trace)
        return j + tiebreak(full, trace) if tie else j


# ----------------------------------------------------------------------------------------------------------
# 4. J(theta) of each method; per-design BO's objective
# ----------------------------------------------------------------------------------------------------------
@dataclass
class PolicyJ:
    """J(theta) of one policy for every design (an e2e MLP / MoE, or the baseline design's policy)."""
    policy: object
    space: ballu.DesignSpace
    task: str
    preset: Preset
    workers: int = 1
    label: str = ""
    trace: dict | None = None   # see score_policy

    def __call__(self, theta):
        out = score_policy(self.policy, self.space.full(theta), self.task, self.preset, self.workers, self.label,
                           trace=self.trace)
        return float(out[0]) if np.ndim(theta) == 1 else out


def ges_J(run_dir: str, task: str, space: ballu.DesignSpace, preset: Preset, workers: int = 1,
          label: str = "", trace: dict | None = None) -> ges.RoutedEvaluator:
    """J(theta) of GES (paper Sec. IV-C): the density router (eq. 10) hands each design to the specialist whose
    Gaussian is densest there, and that specialist plays it (the paper's J, never the probe schedule)."""
    res = load_ges(run_dir)
    for c in res.ckpt:   # each specialist read back once here: TPE would count a damaged one as failed trials
        load_ges_ckpt(c, preset)
    return ges.routed_evaluator(res, ScoreSpecialist(task, space, preset, workers, label, trace=trace))


def ges_specialist(run_dir: str, theta, preset: Preset):
    """The policy of the specialist the router (eq. 10) picks for one design theta (the space's coordinates)."""
    res = load_ges(run_dir)
    return load_ges_ckpt(res.ckpt[int(res.route(theta)[0])], preset)


def policy_ckpt(run: Run, name: str) -> str:
    return run.path("policies", name, "policy.pt")


def load_policy(run: Run, method: str, task: str, sp: str):
    """The policy of a single-policy method ('baseline' = the baseline design's own policy, 'mlp', 'moe')."""
    name = f"baseline-{task}" if method == "baseline" else f"{method}-{task}-{sp}"
    return read_back(ppo.scored_path(policy_ckpt(run, name), run.preset.policy_rule),
                     ppo.load_policy, "ppo.py checkpoint")


def method_J(run: Run, method: str, task: str, sp: str, label: str = "", trace: dict | None = None):
    """J(theta) of a method on designs of its task/space: (d,) -> float, (n, d) -> (n,)."""
    space = space_of(run.preset, task, sp)
    if method == "ges":
        return ges_J(run.path("ges", run.main_ges(task, sp)), task, space, run.preset,
                     run.workers, label, trace)
    return PolicyJ(load_policy(run, method, task, sp), space, task, run.preset, run.workers, label, trace)


@dataclass
class PerDesignBO:
    """The cost baseline's objective: every TPE trial trains a fresh PPO policy on its one design with the
    per-policy budget (ppo_steps), then scores it. The policy folder is named by the design, so a killed
    trial resumes its own training. One process on one core per trial, as every training job of a run."""
    run: Run
    task: str
    space: ballu.DesignSpace

    def folder(self, theta) -> str:
        return self.run.path("policies", "bo", self.name(theta))

    @staticmethod
    def name(theta) -> str:
        return hashlib.sha1(np.asarray(theta, dtype=float).tobytes()).hexdigest()[:12]

    def __call__(self, theta):
        full, name, folder = self.space.full(theta), self.name(theta), self.folder(theta)
        ckpt = train_policy(os.path.join(folder, "policy.pt"), "mlp", self.task, ballu.FixedDesign(full[0]),
                            self.run.preset.ppo_steps, self.run.preset, derive_seed(self.run.seed, "bo", name),
                            f"bo {name}")
        t0 = time.time()
        y = PolicyJ(ppo.load_policy(ppo.scored_path(ckpt, self.run.preset.policy_rule)), self.space, self.task,
                    self.run.preset)(theta)
        write_json(os.path.join(folder, "seconds.json"),
                   {"train_s": train_seconds(os.path.join(folder, "log.csv")), "score_s": time.time() - t0})
        return y

    def trial_seconds(self, trial) -> float:
        """One trial's cost: its training over every attempt plus its J. tpe times only the call that finished
        the trial, which a resumed training makes too short; a trial without seconds.json keeps tpe's time."""
        try:
            sec = read_json(os.path.join(self.folder(trial.x), "seconds.json"))
            return float(sec["train_s"] + sec["score_s"])
        except (OSError, *READ_ERRORS):
            return float(trial.seconds or 0.0)


# ----------------------------------------------------------------------------------------------------------
# 5. Machinery: a GES run's files read back, seeds, the --rates job
# ----------------------------------------------------------------------------------------------------------
def ges_fix(run_dir: str) -> str:
    """What to do about a damaged file of a GES run: its rounds cannot be redone alone."""
    return (f"{FRESH}, or delete the folder {run_dir} and the stages/*.json of ges and every later stage to "
            f"redo only that GES run (all other work files are reused)")


def load_ges(run_dir: str) -> ges.GESResult:
    return read_back(os.path.join(run_dir, ges.STATE_FILE), lambda p: ges.load_result(run_dir), "GES state",
                     ges_fix(run_dir))


def load_ges_ckpt(ckpt: str, preset: Preset):
    """A GES specialist's policy (ckpt inside <run_dir>/ckpt/: its last round's), by the preset's policy_rule."""
    return read_back(ppo.scored_path(ckpt, preset.policy_rule), ppo.load_policy, "ppo.py checkpoint",
                     ges_fix(os.path.dirname(os.path.dirname(ckpt))))


def derive_seed(seed: int, *names) -> int:
    """A seed for one consumer (a policy, a GES run, a TPE study), derived from --seed and stable names, so
    results do not depend on the order in which things run."""
    return ges.seed_for(seed, *(zlib.crc32(str(n).encode()) for n in names)) % 2 ** 31   # names as CRC-32 keys


def ckpt_steps(path: str) -> int:
    return int(ppo.load_checkpoint(path)["steps"])


def rate_job(folder: str, kind: str, task: str, seed: int, preset: Preset, steps: int = 40_960,
             n_designs: int = 3) -> tuple:
    """One job of `--rates` or a calibration, as a stage runs it (in-process env, one core): train an e2e `kind`
    on `task` D2 for `steps`, then J of that policy on `n_designs` uniform D2 designs, timed by runkit.plan.job_rates
    (PPO steps/s over the updates after the first, s per J, played score steps/s)."""
    space, ckpt, stats = space_of(preset, task, "d2"), os.path.join(folder, "policy.pt"), {}

    def score() -> int:   # the control steps J played (replays excluded)
        designs = space.sample_uniform(np.random.default_rng(seed), n_designs)
        score_policy(ppo.load_policy(ppo.scored_path(ckpt, preset.policy_rule)), space.full(designs), task, preset,
                     1, stats=stats)
        return stats["episodes_played"] * preset.env_config(ballu.BalluConfig()).episode_steps

    return job_rates(lambda: train_policy(ckpt, kind, task, ballu.UniformDesign(space), steps, preset, seed), score,
                     os.path.join(folder, "log.csv"), steps, n_designs)
