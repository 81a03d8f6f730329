"""ppo.py -- PPO from scratch in torch, with the MLP and MoE actor-critics of the GES paper.

Read top to bottom:
  1. settings (`PPOConfig`)                         -- docs/facts.md "PPO as they ran it"
  2. running observation normalisation
  3. actor-critics: `MLPActorCritic` (e2e MLP and every GES specialist), `MoEActorCritic` (e2e MoE)
  4. GAE and the PPO update (clipped surrogate, value loss, entropy bonus, adaptive-KL learning rate)
     4b. the options off by default (squashed actions, reward scaling, split gradient clip, std bound)
  5. the training loop: `train(...)`, each update rollout -> GAE -> PPO update -> log, curriculum, a checkpoint
     every cfg.ckpt_every updates
  6. the loop's parts: `start_run` (fresh, warm start or resume), `rollout` (here or in the env's workers),
     `TrainLog` (CSV + progress line), learning curve
  7. checkpoints and resume: the last, and the best by training level (`scored_path`); a killed run resumed
     exactly; files written by older code
  8. loading a checkpoint as a plain `obs -> action` callable (for ballu.score and the strips)
  9. benchmark: end-to-end training against stepping the env alone (`python ppo.py bench`)

This module imports no env: training one policy on BALLU is `python -m experiments.ppo_ballu train`, comparing
PPO settings on it `python -m experiments.ppo_protocol` (docs/ppo_protocol).

The env is anything with the batched interface of ballu.py: `num_envs`, `obs_dim`, `act_dim`,
`reset(seed=, options=) -> (obs, info)` and `step(actions) -> (obs, reward, terminated, truncated, info)` with
the last observation of finished episodes in info["final_obs"] (rows flagged by info["_final_obs"]).
A multi-process env may also offer `parts` (lane ids per worker) and `run(fn, args)` (fn(worker env, *args[k])
in each worker k): the trainer then rolls out in the workers, one policy copy each (see `rollout`).
"""
from __future__ import annotations

import csv
import math
import os
import time
import warnings
from collections import deque
from dataclasses import asdict, dataclass

import numpy as np
import torch
import torch.nn as nn

from runkit.files import atomic
from runkit.settings import integer, need   # a bad setting: one line
from runkit.progress import eta_s


# ----------------------------------------------------------------------------------------------------------
# 1. Settings
# ----------------------------------------------------------------------------------------------------------
@dataclass
class PPOConfig:
    """PPO settings: [facts] = the authors' runs (docs/facts.md), [ours] = adapted to training on a few CPU cores.

    The fixed protocol of docs/ppo_protocol screened batch shape, epochs, entropy bonus, std bound, squashed
    actions, reward form and scale, observation clip, gradient clip, learning-rate cap and curriculum start on
    BALLU (3 seeds where it mattered): only the learning-rate cap (max_lr) and the ramp's spread start
    (ballu.train_start_levels) beat the facts' values beyond the seed spread, so every other value is the facts'
    and every lever stays an option, off by default.

    max_lr: the facts' 1e-2 (rsl_rl's) let the rate jump 1e-5 <-> 1e-2 within a few updates; the cap of 1e-3 gave
    ramp J +6.8 +- 2.7 deg at 2 M steps, 3 seeds, on two CPU models; the obstacle showed no difference beyond its
    scoring noise (docs/ppo_protocol)."""
    hidden: tuple = (128, 64, 32)      # [paper] Sec. V-A actor and critic MLP, ELU
    init_std: float = 0.5              # [facts] initial action std (state independent)
    init_action_mean: float = 0.0      # [ours] bias of the actor's last layer: 0.5 centres BALLU's servo range
    lr: float = 1e-4                   # [facts] initial learning rate, then adaptive KL
    desired_kl: float = 0.01           # [facts] adaptive-KL target
    max_lr: float = 1e-3               # [ours] upper clamp of the adaptive-KL rate (facts: 1e-2; see above)
    clip: float = 0.2                  # [facts]
    entropy_coef: float = 0.01         # [facts] kept: 0 ended lowest in the screen (docs/ppo_protocol)
    max_std: float = 0.0               # [ours] > 0: the action std is held <= this after each step (0 = free)
    squash: bool = False               # [ours] True: the env gets sigmoid(u) in (0, 1), not u clipped (`to_env`)
    split_clip: bool = False           # [ours] True: actor and critic gradients are norm-clipped apart (screened)
    reward_norm: bool = False          # [ours] rewards / running std of the discounted return (see scale_rewards)
    value_coef: float = 1.0            # [ours] (rsl_rl's default)
    epochs: int = 5                    # [facts] kept: 10 x 8 gave +1.3 +- 0.9 cm (3 seeds), 2 x 2 lower
    minibatches: int = 4               # [facts]
    gamma: float = 0.99                # [facts]
    lam: float = 0.95                  # [facts]
    max_grad_norm: float = 0.5         # [facts]
    num_envs: int = 32                 # [ours] they ran 4096 envs x 20 steps on a GPU
    num_steps: int = 64                # [ours] rollout length per env and update
    obs_clip: float = 5.0              # [ours] clip of the normalised observation
    moe_experts: int = 6               # [facts] e2e MoE: 6 experts
    gate_hidden: tuple = (64, 32)      # [facts] gate MLP on the design vector
    load_balance_coef: float = 0.01    # [facts] load-balance loss weight
    design_dim: int = 4                # the design vector is the last 4 observation entries (ballu.py)
    ckpt_every: int = 10               # [ours] iterations between checkpoints

    def __post_init__(self):   # one line naming a bad setting and what is allowed (runkit.settings)
        for name in ("epochs", "minibatches", "num_envs", "num_steps", "moe_experts", "design_dim", "ckpt_every"):
            integer(self, name, 1)
        for name in ("init_std", "lr", "desired_kl", "max_lr", "clip", "max_grad_norm", "obs_clip"):
            need(self, name, getattr(self, name) > 0, "a number > 0")
        for name in ("entropy_coef", "max_std", "value_coef", "load_balance_coef"):
            need(self, name, getattr(self, name) >= 0, "a number >= 0")
        need(self, "gamma", 0 < self.gamma <= 1, "in (0, 1]")
        need(self, "lam", 0 <= self.lam <= 1, "in [0, 1]")
        for name in ("squash", "split_clip", "reward_norm"):
            need(self, name, isinstance(getattr(self, name), (bool, np.bool_)), "True or False")

    @property
    def batch(self) -> int:
        return self.num_envs * self.num_steps


# ----------------------------------------------------------------------------------------------------------
# 2. Running observation normalisation (stored in the checkpoint)
# ----------------------------------------------------------------------------------------------------------
class RunningNorm:
    """Mean and variance over every observation seen so far (parallel Welford update)."""

    def __init__(self, dim: int, clip: float = 5.0):
        self.mean, self.var, self.count, self.clip = np.zeros(dim), np.ones(dim), 1e-4, clip

    def update(self, x: np.ndarray):
        m, v, n = x.mean(0), x.var(0), len(x)
        delta, tot = m - self.mean, self.count + n
        self.mean = self.mean + delta * n / tot
        self.var = (self.var * self.count + v * n + delta ** 2 * self.count * n / tot) / tot
        self.count = tot

    def __call__(self, x: np.ndarray, cols: slice = slice(None)) -> np.ndarray:
        """(x - mean) / std, clipped to +-clip; `cols`: x holds only these entries (the MoE gate's design). An entry
        that was constant in training (a single design's design vector) has std ~1e-4, so a value 0.05 % away
        from the training one already reads as +-clip: score a single-design policy on its own design, exactly as
        trained (docs/ppo_protocol)."""
        return np.clip((x - self.mean[cols]) / np.sqrt(self.var[cols] + 1e-8), -self.clip,
                       self.clip).astype(np.float32)

    def state(self) -> dict:
        return {"mean": torch.tensor(self.mean), "var": torch.tensor(self.var), "count": float(self.count)}

    def load(self, s: dict):
        self.mean, self.var, self.count = s["mean"].numpy().copy(), s["var"].numpy().copy(), float(s["count"])


# ----------------------------------------------------------------------------------------------------------
# 3. Actor-critics
# ----------------------------------------------------------------------------------------------------------
def mlp(sizes, out_gain=1.0) -> nn.Sequential:
    """ELU MLP with orthogonal init (gain sqrt(2) inside, `out_gain` on the last layer), zero biases."""
    layers = []
    for i in range(len(sizes) - 1):
        lin = nn.Linear(sizes[i], sizes[i + 1])
        last = i == len(sizes) - 2
        nn.init.orthogonal_(lin.weight, out_gain if last else math.sqrt(2))
        nn.init.zeros_(lin.bias)
        layers += [lin] if last else [lin, nn.ELU()]
    return nn.Sequential(*layers)


class MLPActorCritic(nn.Module):
    """Gaussian policy with a state-independent std and a separate critic. [paper] Sec. V-A"""

    def __init__(self, obs_dim: int, act_dim: int, cfg: PPOConfig = PPOConfig()):
        super().__init__()
        self.actor = mlp([obs_dim, *cfg.hidden, act_dim], out_gain=0.01)
        nn.init.constant_(self.actor[-1].bias, cfg.init_action_mean)
        self.critic = mlp([obs_dim, *cfg.hidden, 1], out_gain=1.0)
        self.log_std = nn.Parameter(torch.full((act_dim,), math.log(cfg.init_std)))

    def mean(self, obs):
        return self.actor(obs)

    def value(self, obs):
        return self.critic(obs).squeeze(-1)

    def aux_loss(self, obs):
        return torch.zeros(())


class MoEActorCritic(nn.Module):
    """e2e MoE baseline: K expert actors on the full observation, mixed by a soft gate on the design vector.

    mean = sum_k softmax(gate(theta_m))_k * expert_k(s~); one shared critic; a load-balance loss keeps the
    batch-average gate weights near uniform. [facts] "MoE baseline"
    """

    def __init__(self, obs_dim: int, act_dim: int, cfg: PPOConfig = PPOConfig()):
        super().__init__()
        self.design_dim, self.k, self.lb = cfg.design_dim, cfg.moe_experts, cfg.load_balance_coef
        self.experts = nn.ModuleList(mlp([obs_dim, *cfg.hidden, act_dim], out_gain=0.01) for _ in range(self.k))
        for e in self.experts:
            nn.init.constant_(e[-1].bias, cfg.init_action_mean)
        self.gate = mlp([cfg.design_dim, *cfg.gate_hidden, self.k], out_gain=0.01)
        self.critic = mlp([obs_dim, *cfg.hidden, 1], out_gain=1.0)
        self.log_std = nn.Parameter(torch.full((act_dim,), math.log(cfg.init_std)))

    def gate_weights(self, design_obs):
        """Softmax gate weights (n, K) for the design part of (normalised) observations (n, design_dim)."""
        return torch.softmax(self.gate(design_obs), dim=-1)

    def mean(self, obs):
        w = self.gate_weights(obs[:, -self.design_dim:])
        mus = torch.stack([e(obs) for e in self.experts], dim=1)       # (n, K, act)
        return (w.unsqueeze(-1) * mus).sum(1)

    def value(self, obs):
        return self.critic(obs).squeeze(-1)

    def aux_loss(self, obs):
        """Load balance: K * sum_k (mean gate weight k)^2 - 1, zero when experts are used equally."""
        w = self.gate_weights(obs[:, -self.design_dim:]).mean(0)
        return self.lb * (self.k * (w ** 2).sum() - 1.0)


POLICIES = {"mlp": MLPActorCritic, "moe": MoEActorCritic}


def make_policy(kind: str, obs_dim: int, act_dim: int, cfg: PPOConfig = PPOConfig()) -> nn.Module:
    if kind not in POLICIES:
        raise ValueError(f"policy kind={kind!r} is not one of {tuple(POLICIES)}")
    return POLICIES[kind](obs_dim, act_dim, cfg)


def gaussian_log_prob(act, mean, log_std):
    """log N(act; mean, exp(log_std)) summed over action dims: the policy's log-probability, written out
    (a torch Distribution object costs more than this arithmetic in the small-batch update)."""
    z = (act - mean) * torch.exp(-log_std)
    return (-0.5 * z * z - log_std - 0.5 * math.log(2 * math.pi)).sum(-1)


# ----------------------------------------------------------------------------------------------------------
# 4. GAE and the PPO update
# ----------------------------------------------------------------------------------------------------------
def gae(rewards, values, dones, last_value, gamma: float, lam: float):
    """Generalised advantage estimation over (T, N) arrays.

    dones[t] = 1 where the episode ended at step t (terminated or truncated). A truncated step's reward
    must already hold gamma * V(final observation) (the time-limit bootstrap); the trace is cut there.
    Returns (advantages, returns).
    """
    T = len(rewards)
    adv = np.zeros_like(rewards)
    last = np.zeros_like(last_value)
    for t in reversed(range(T)):
        next_v = last_value if t == T - 1 else values[t + 1]
        nonterminal = 1.0 - dones[t]
        delta = rewards[t] + gamma * next_v * nonterminal - values[t]
        last = delta + gamma * lam * nonterminal * last
        adv[t] = last
    return adv, adv + values


def ppo_update(policy, opt, batch: dict, cfg: PPOConfig, lr: float, rng: np.random.Generator):
    """Several epochs of clipped-surrogate minibatch steps; the learning rate follows the KL. [facts]"""
    n = len(batch["obs"])
    adv = batch["adv"]
    adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    stats = {"kl": [], "policy_loss": [], "value_loss": [], "entropy": []}
    mb = n // cfg.minibatches
    for _ in range(cfg.epochs):
        perm = torch.from_numpy(rng.permutation(n))
        for s in range(0, mb * cfg.minibatches, mb):
            idx = perm[s:s + mb]
            obs, act = batch["obs"][idx], batch["act"][idx]
            mu, log_std = policy.mean(obs), policy.log_std
            logp = gaussian_log_prob(act, mu, log_std)
            with torch.no_grad():   # KL(old || new) of two diagonal Gaussians, for the schedule
                old_mu, old_std, std = batch["mu"][idx], batch["std"][idx], log_std.exp()
                kl = (torch.log(std / old_std) + (old_std ** 2 + (old_mu - mu) ** 2)
                      / (2 * std ** 2) - 0.5).sum(-1).mean().item()
            if kl > 2 * cfg.desired_kl:
                lr = max(1e-5, lr / 1.5)
            elif 0 < kl < cfg.desired_kl / 2:
                lr = min(cfg.max_lr, lr * 1.5)
            for g in opt.param_groups:
                g["lr"] = lr
            ratio = torch.exp(logp - batch["logp"][idx])
            a = adv[idx]
            policy_loss = -torch.min(ratio * a, torch.clamp(ratio, 1 - cfg.clip, 1 + cfg.clip) * a).mean()
            value_loss = (policy.value(obs) - batch["ret"][idx]).pow(2).mean()
            entropy = entropy_bonus(mu, log_std, act, old_mu, old_std, cfg)   # the options: section 4b
            loss = policy_loss + cfg.value_coef * value_loss - cfg.entropy_coef * entropy + policy.aux_loss(obs)
            opt.zero_grad()
            loss.backward()
            clip_gradients(policy, cfg)
            opt.step()
            bound_std(policy, cfg)
            for k, v in (("kl", kl), ("policy_loss", policy_loss.item()), ("value_loss", value_loss.item()),
                         ("entropy", entropy.item())):
                stats[k].append(v)
    return lr, {k: float(np.mean(v)) for k, v in stats.items()}


# ----------------------------------------------------------------------------------------------------------
# 4b. The options [ours], each off by default (PPOConfig: squash, reward_norm, split_clip, max_std): the paper's
#     path is each function's first branch; the update and the loop call them without a branch of their own
# ----------------------------------------------------------------------------------------------------------
def to_env(u, cfg: PPOConfig):
    """The action the env gets for the Gaussian sample (or mean) u: u itself (the env clips it to its range), or
    sigmoid(u) if `cfg.squash` [ours, an option]. Squashed, a policy whose mean is far outside [0, 1] still gets
    a gradient (a clipped action is the same for every mean beyond the bound). PPO keeps u: the ratio
    p_new(a) / p_old(a) of the squashed actions equals that of u (the Jacobian |da/du| cancels), and the KL of
    the two policies is the same in u and a, so only the entropy needs the Jacobian (`entropy_bonus`)."""
    return 1.0 / (1.0 + np.exp(-u)) if cfg.squash else u


def scale_rewards(buf, acc, ret_norm: RunningNorm, cfg: PPOConfig) -> np.ndarray:
    """The (T, N) rewards GAE sees: the env's rewards, divided by the running std of each lane's discounted
    return if `cfg.reward_norm` (CleanRL's NormalizeReward), plus the time-limit bootstrap gamma * V(final
    observation), which is already in the critic's units. `acc` (N,) carries each lane's discounted return
    across rollouts and is updated in place, as is `ret_norm`.

    [ours, an option] BALLU's dt-scaled eq. 4 rewards give returns of ~-60 to -250 (value loss 15-40 at 1 M
    steps); scaled, the critic's targets are O(1) whatever the reward form, its scale or the design."""
    if not cfg.reward_norm:
        return buf["rew"] + buf["boot"]
    disc = np.empty_like(buf["rew"])
    for t in range(len(disc)):
        acc *= cfg.gamma
        acc += buf["rew"][t]
        disc[t] = acc
        acc[buf["done"][t] > 0] = 0.0
    ret_norm.update(disc.reshape(-1, 1))
    return (buf["rew"] / np.sqrt(ret_norm.var[0] + 1e-8)).astype(np.float32) + buf["boot"]


def entropy_bonus(mu, log_std, act, old_mu, old_std, cfg: PPOConfig):
    """The policy's entropy for the bonus. Of N(mu, std) it is state independent; of the squashed action
    a = sigmoid(u) it is that plus E[log sigmoid'(u)], estimated on the minibatch's samples `act` (drawn as
    old_mu + old_std * eps in the rollout) moved with the new mean and std (u = mu + std * eps), so widening u
    into the flat ends of the sigmoid earns no bonus."""
    h = (log_std + 0.5 * math.log(2 * math.pi * math.e)).sum()
    if not cfg.squash:
        return h
    eps = (act - old_mu) / old_std
    u = mu + log_std.exp() * eps
    return h - (nn.functional.softplus(u) + nn.functional.softplus(-u)).sum(-1).mean()


def clip_gradients(policy, cfg: PPOConfig):
    """One norm clip over all weights [facts, rsl_rl], or actor and critic apart if `cfg.split_clip` [ours,
    an option]: the critic's gradient (value loss 15-40 on dt-scaled BALLU rewards) otherwise sets the scale
    of the actor's step."""
    if not cfg.split_clip:
        nn.utils.clip_grad_norm_(policy.parameters(), cfg.max_grad_norm)
        return
    critic = set(map(id, policy.critic.parameters()))
    nn.utils.clip_grad_norm_(list(policy.critic.parameters()), cfg.max_grad_norm)
    nn.utils.clip_grad_norm_([p for p in policy.parameters() if id(p) not in critic], cfg.max_grad_norm)


def bound_std(policy, cfg: PPOConfig):
    """After each step, the action std held <= `cfg.max_std` if > 0 [ours, an option]: a projection of the
    log-std, so the std cannot run away."""
    if cfg.max_std > 0:
        with torch.no_grad():
            policy.log_std.clamp_(max=math.log(cfg.max_std))


# ----------------------------------------------------------------------------------------------------------
# 5. The training loop
# ----------------------------------------------------------------------------------------------------------
@dataclass
class TrainState:
    """What a run carries from update to update; a checkpoint holds all of it (save_checkpoint)."""
    policy: nn.Module
    norm: RunningNorm
    opt: torch.optim.Optimizer
    rng: np.random.Generator
    lr: float
    steps: int                         # control steps since the run's first update ever
    levels: np.ndarray                 # each lane's curriculum level
    ret_norm: RunningNorm              # the return statistics of cfg.reward_norm
    best: dict                         # the best policy's record (next_best)
    own: dict | None = None            # the checkpoint's whole state when the run resumes its own checkpoint


def train(kind: str, env, design_sampler, total_steps: int, ckpt: str, cfg: PPOConfig = PPOConfig(),
          init_ckpt: str | None = None, seed: int = 0, start_level: int | tuple = 0, log_csv: str | None = None,
          progress=print) -> dict:
    """Train a `kind` ('mlp' | 'moe') policy with PPO until `total_steps` control steps, counted from the run's
    first update ever (a warm start carries its steps, so a GES round trains total_steps minus them).

    `design_sampler(rng, n) -> (n, 4)` draws the designs of resetting lanes (uniform over a design space for
    the e2e baselines, a GES territory for a specialist). Where the run starts: start_run (resume, warm start,
    fresh). Each update: rollout -> GAE -> PPO update -> log, and every cfg.ckpt_every updates a checkpoint
    (checkpoint: the run, and the best policy by training level). Returns a summary of the last update and the
    best one, and whether the run resumed from `ckpt`."""
    if env.num_envs < 1 or total_steps < 1:
        raise ValueError(f"env.num_envs={env.num_envs!r} and total_steps={total_steps!r} must be >= 1")
    torch.set_num_threads(1)   # the env workers own the cores; the update is small
    resumed = os.path.exists(ckpt)
    st = start_run(kind, env, ckpt, init_ckpt, cfg, seed, start_level)
    if st.steps >= total_steps:
        return {"steps": st.steps, "resumed": True}
    obs, acc, ep_returns = start_episodes(env, st, design_sampler, progress)
    T, N, window = cfg.num_steps, env.num_envs, []
    with TrainLog(log_csv, progress, kind, total_steps) as log:
        while st.steps < total_steps:
            t0 = time.time()
            # rollout: T steps on every lane, then the normaliser's update with what the lanes observed
            if hasattr(env, "schedule"):   # an env whose schedule follows training's progress (a warm-up)
                env.schedule(st.steps)
            noise_seed = int(st.rng.integers(2 ** 31))
            buf, obs, info, finished = rollout(kind, st.policy, st.norm, env, obs, T, cfg, noise_seed)
            # GAE: advantages and returns over the (T, N) rollout
            last_value = value_of(st.policy, st.norm, obs)   # bootstrap of the episodes the rollout cut off
            rew = scale_rewards(buf, acc, st.ret_norm, cfg)
            adv, ret = gae(rew, buf["val"], buf["done"], last_value, cfg.gamma, cfg.lam)
            # PPO update: epochs of minibatches from the flattened rollout, the rate following the KL
            std = st.policy.log_std.exp().detach()
            batch, t_roll = flatten_batch(buf, adv, ret, std), time.time() - t0
            st.lr, stats = ppo_update(st.policy, st.opt, batch, cfg, st.lr, st.rng)
            # log: steps, curriculum levels, the last 100 episodes' return; a checkpoint every cfg.ckpt_every updates
            st.steps, st.levels = st.steps + T * N, np.asarray(info["levels"])
            ep_returns.extend(finished)
            window.append(float(st.levels.mean()))
            ep_ret = float(np.mean(ep_returns)) if ep_returns else float("nan")   # of the last 100 episodes
            log.write(st.steps, T * N, t0, t_roll, float(buf["rew"].mean()), ep_ret, window[-1], stats, st.lr,
                      float(std.mean()))
            if len(window) == cfg.ckpt_every or st.steps >= total_steps:
                checkpoint(ckpt, st, kind, cfg, env, float(np.mean(window)), obs, acc, ep_returns,
                           st.steps >= total_steps)
                window.clear()
    return {"steps": st.steps, "mean_level": float(st.levels.mean()), "episode_return": ep_ret,
            "wall_s": time.time() - log.t_start, "best_level": st.best["level"], "best_steps": st.best["steps"],
            "resumed": resumed}


# ----------------------------------------------------------------------------------------------------------
# 6. The loop's parts: where a run starts, the rollout, the log
# ----------------------------------------------------------------------------------------------------------
def value_of(policy, norm, obs) -> np.ndarray:
    """The critic's V of raw observations (normalised here): the bootstrap of an episode a rollout cut off."""
    with torch.inference_mode():
        return policy.value(torch.from_numpy(norm(obs))).numpy()


def start_run(kind, env, ckpt, init_ckpt, cfg, seed, start_level) -> TrainState:
    """Where a run starts: resumed from `ckpt` if it exists (random streams included: `own`), else warm-started
    from `init_ckpt` (policy, optimiser, normaliser, curriculum levels and the step count: a GES round), else
    fresh from `seed`, every lane at curriculum level `start_level`, or at a uniform level in (low, high)
    [ours: lets the policy meet the levels that the score J plays without climbing one level per episode].
    A checkpoint of another policy kind, size or observation is a clear error. Resume and warm start: section 7
    (checked_policy, resume_from)."""
    resume = ckpt if os.path.exists(ckpt) else init_ckpt
    state = load_checkpoint(resume) if resume else None
    if resume != ckpt:
        torch.manual_seed(seed)   # before the policy is built: fresh weights depend on the seed only
    if state is None:
        policy, norm = make_policy(kind, env.obs_dim, env.act_dim, cfg), RunningNorm(env.obs_dim, cfg.obs_clip)
    else:
        policy, norm = checked_policy(state, resume, kind, env)
    opt = torch.optim.Adam(policy.parameters(), lr=cfg.lr, foreach=True)   # one fused call per step
    rng = np.random.default_rng([seed, 1])
    if isinstance(start_level, (tuple, list)):   # (low, high): each lane starts at a uniform level in between
        levels = rng.integers(start_level[0], start_level[1] + 1, env.num_envs)
    else:
        levels = np.full(env.num_envs, start_level)
    st = TrainState(policy, norm, opt, rng, cfg.lr, 0, levels, RunningNorm(1), dict(NO_BEST))
    if state is not None:
        resume_from(st, state, env, own=resume == ckpt)
    return st


def start_episodes(env, st: TrainState, design_sampler, progress):
    """The run's first observations, the running discounted returns of cfg.reward_norm and the last 100 episode
    returns: where the run's own checkpoint left them (resume_env), else fresh episodes."""
    acc, ep_returns = np.zeros(env.num_envs, dtype=np.float32), deque(maxlen=100)
    obs = resume_env(env, st.own, design_sampler, progress)
    if obs is not None:
        acc[:] = st.own["run"]["acc"].numpy()
        ep_returns.extend(st.own["run"]["ep_returns"])
        return obs, acc, ep_returns
    obs, _ = env.reset(seed=int(st.rng.integers(2 ** 31)), options={"design_sampler": design_sampler,
                                                                      "levels": st.levels})
    st.norm.update(obs)
    return obs, acc, ep_returns


def rollout(kind, policy, norm, env, obs, T: int, cfg: PPOConfig, noise_seed: int):
    """One rollout of T steps on all lanes, then the normaliser update with every observation that arrived.

    Layout [ours, measured fastest]: a multi-process env (one with `run`, ballu.VecBallu) gets the policy's
    weights and each worker rolls out its own lanes with a local copy, so no step waits for the trainer
    (stepping the workers from here costs a round trip per 20 Hz step: `python ppo.py bench`). Any other env
    is rolled out in this process."""
    if hasattr(env, "run"):
        weights = {k: v.numpy() for k, v in policy.state_dict().items()}   # arrays: a sent tensor goes to shared memory
        parts = env.run(_rollout_in_worker, [(kind, cfg, weights, norm, obs[ids], T, noise_seed) for ids in env.parts])
        bufs, obss, infos, rets = zip(*parts)
        join = lambda dicts, axis: {k: np.concatenate([np.asarray(d[k]) for d in dicts], axis) for k in dicts[0]}
        buf, info = join(bufs, 1), join(infos, 0)   # buffers are (T, lanes, ...)
        obs, returns = np.concatenate(obss), [r for ret in rets for r in ret]
    else:
        buf, obs, info, returns = rollout_lanes(env, policy, norm, obs, T, cfg, noise_seed)
    norm.update(buf.pop("new_obs").reshape(-1, obs.shape[1]))
    return buf, obs, info, returns


def rollout_lanes(env, policy, norm, obs, T: int, cfg: PPOConfig, noise_seed: int):
    """T steps on every lane of `env`, run where the env lives (this process, or a worker process holding its
    own policy copy): returns the buffers (T, n, ...), the raw observations that arrived (for the normaliser),
    the last observations and info, and the returns of finished episodes. Time-limit ends are bootstrapped
    with V(final observation).

    The normaliser's statistics are frozen for the rollout (the trainer updates them after it). Lane i's noise
    comes from rng([noise_seed, lane id]), so how the lanes are split over workers changes nothing but float
    rounding (batched matmuls of other sizes; contact physics amplifies it, so such runs drift apart)."""
    n, A = len(obs), policy.log_std.shape[0]
    lane_ids = getattr(env, "lane_ids", np.arange(n))
    eps = np.stack([np.random.default_rng([noise_seed, int(i)]).standard_normal((T, A), dtype=np.float32)
                    for i in lane_ids], axis=1)                      # (T, n, A)
    buf = {k: np.zeros((T, n) + s, dtype=np.float32) for k, s in
           (("obs", (obs.shape[1],)), ("act", (A,)), ("mu", (A,)), ("rew", ()), ("boot", ()), ("done", ()),
            ("val", ()))}
    buf["new_obs"] = np.zeros((T,) + obs.shape, dtype=obs.dtype)
    log_std = policy.log_std.detach()
    std = log_std.exp().numpy()
    # log N(a; mu, std) with (a - mu) / std = eps: no distribution object in the hot loop
    logp_0 = -log_std.sum().item() - 0.5 * A * math.log(2 * math.pi)
    buf["logp"] = (logp_0 - 0.5 * (eps ** 2).sum(-1)).astype(np.float32)
    returns = []
    for t in range(T):
        o = torch.from_numpy(norm(obs))
        with torch.inference_mode():
            mu, v = policy.mean(o).numpy(), policy.value(o).numpy()
        a = mu + std * eps[t]
        buf["obs"][t], buf["act"][t], buf["mu"][t], buf["val"][t] = o.numpy(), a, mu, v
        obs, rew, term, trunc, info = env.step(to_env(a, cfg))
        if trunc.any():   # time-limit end: bootstrap with V(final observation), kept apart from the reward
            buf["boot"][t][trunc] = cfg.gamma * value_of(policy, norm, info["final_obs"][trunc])
        done = term | trunc
        returns.extend(info["episode_return"][done].tolist())
        buf["rew"][t], buf["done"][t], buf["new_obs"][t] = rew, done, obs
    return buf, obs, info, returns


def flatten_batch(buf, adv, ret, std) -> dict:
    """The (T, N, ...) rollout as (T * N, ...) tensors for the minibatches; `std` is the rollout's action std."""
    flat = lambda x: torch.from_numpy(np.ascontiguousarray(x.reshape((-1,) + x.shape[2:])))
    batch = {k: flat(buf[k]) for k in ("obs", "act", "mu", "logp")}
    batch.update(adv=flat(adv), ret=flat(ret), std=std.expand(len(batch["obs"]), -1))
    return batch


class TrainLog:
    """Per update, one row appended to the CSV log (if `log_csv`) and one progress line (if `progress`)."""
    COLUMNS = ["steps", "wall_s", "steps_per_s", "mean_reward", "episode_return", "mean_level", "kl", "lr",
               "value_loss", "entropy", "std"]

    def __init__(self, log_csv, progress, kind: str, total_steps: int):
        self.file = open(log_csv, "a", newline="") if log_csv else None
        self.csv = csv.writer(self.file) if self.file else None
        if self.file and self.file.tell() == 0:
            self.csv.writerow(self.COLUMNS)
        self.progress, self.kind, self.total_steps, self.t_start = progress, kind, total_steps, time.time()

    def write(self, steps, n, t0, t_roll, reward, ep_ret, level, st, lr, std):
        """The update that began at time t0 and ended at `steps`: `n` steps, `t_roll` seconds of rollout."""
        dt = time.time() - t0
        rate = n / dt
        row = [steps, round(time.time() - self.t_start, 2), round(rate, 1), reward, ep_ret, level, st["kl"], lr,
               st["value_loss"], st["entropy"], std]
        if self.csv:
            self.csv.writerow(row)
            self.file.flush()
        if self.progress:
            time_left_s = eta_s(dt, n, self.total_steps - steps)   # at the last update's pace
            ret = f"{ep_ret:+8.2f}" if math.isfinite(ep_ret) else f"{'-':>8}"   # no episode has ended yet
            self.progress(f"[{self.kind}] {steps:>9,}/{self.total_steps:,} steps  {rate:6.0f} steps/s (rollout "
                          f"{100 * t_roll / dt:3.0f}%)  reward {reward:+.3f}  return {ret}  "
                          f"level {level:5.1f}  kl {st['kl']:.4f}  lr {lr:.1e}  std {std:.2f}  "
                          f"eta {time_left_s / 60:5.1f} min")

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if self.file:
            self.file.close()


def plot_learning_curve(log_csv: str, path: str, title: str = ""):
    """Mean episode return and mean curriculum level against control steps, from a train() CSV log."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    with open(log_csv) as f:
        rows = list(csv.DictReader(f))
    steps = np.array([float(r["steps"]) for r in rows])
    fig, ax = plt.subplots(1, 2, figsize=(9, 3.2))
    ax[0].plot(steps, [float(r["episode_return"]) for r in rows])
    ax[0].set(xlabel="control steps", ylabel="episode return (last 100)")
    ax[1].plot(steps, [float(r["mean_level"]) for r in rows])
    ax[1].set(xlabel="control steps", ylabel="mean curriculum level")
    fig.suptitle(title or os.path.basename(log_csv))
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


# Rolling out in the env's workers (`rollout` with a multi-process env): each worker keeps a policy copy
_POLICY_COPIES = {}   # a worker's policy per (kind, weight shapes): built once (ms), then only given new weights


def _rollout_in_worker(env, kind, cfg, weights, norm, obs, T, noise_seed):
    """`rollout_lanes` in one worker of a multi-process env (called there by env.run), with its policy copy."""
    key = (kind, *(w.shape for w in weights.values()))
    if key not in _POLICY_COPIES:
        torch.set_num_threads(1)   # the workers own the cores, one each
        _POLICY_COPIES[key] = make_policy(kind, env.obs_dim, env.act_dim, cfg)
    policy = _POLICY_COPIES[key]
    policy.load_state_dict({k: torch.from_numpy(w) for k, w in weights.items()})
    return rollout_lanes(env, policy, norm, obs, T, cfg, noise_seed)


# ----------------------------------------------------------------------------------------------------------
# 7. Checkpoints and resume
# ----------------------------------------------------------------------------------------------------------
# A run's checkpoint holds its whole TrainState (save_checkpoint). Every cfg.ckpt_every updates the loop saves it
# and, before it, the best policy by training level (checkpoint, next_best); a score plays scored_path's. A killed
# run, rerun, resumes its own checkpoint exactly (start_run -> checked_policy, resume_from; resume_env).
# Files written by older code still load, train on and score the same, each where it is read: a checkpoint
# without obs_names is checked by size (checked_policy; ballu.policy_config when scored), one without ret_norm
# or a best record resumes without them (resume_from), a best record without "first" keeps the plain rule
# (next_best), one without the env's state starts fresh episodes (resume_env), and a run trained before the
# best checkpoint existed is scored on its last (scored_path).

CKPT_VERSION = 1
# torch pickles an empty bytes (a lane's actions at the very start of its episode, ballu's BalluEnv.get_state) as
# a call of bytes(), which torch.load(weights_only=True) refuses by default: a checkpoint taken just as every
# lane's episode began would read as damaged and its training start over. bytes() builds only bytes.
# Process-wide, once: torch's safe_globals() context is not thread-safe (run_all's threads).
torch.serialization.add_safe_globals([bytes])


def checkpoint(ckpt, st: TrainState, kind, cfg, env, level, obs, acc, ep_returns, finished: bool):
    """Save the run to `ckpt` (every cfg.ckpt_every updates and at the end) and, if the mean training level
    `level` of the updates since the last checkpoint beats the best so far (next_best), first to
    best_path(ckpt) [facts: the authors keep the update with the highest mean level]. [ours] The mean over
    ckpt_every updates, not one update's: 32 lanes' mean level moves by chance from update to update, and a
    best taken only at checkpoints is rewritten bit for bit by a run resumed after a kill.
    [ours] An unfinished run's checkpoint also holds the env's state (if the env has get_state: each lane's
    design, level, clock, random stream and episode so far) and the last observations, so a run killed and rerun
    goes on exactly as if never stopped; without it a resumed run is another run (docs/ppo_protocol "Resumed
    runs"). A finished run's holds none: continuing it to more steps starts fresh episodes, as a warm start does."""
    names = obs_names_of(env)
    new = next_best(st.best, level, st.steps)
    if new is not None:   # the best first: a kill in between redoes both
        st.best = new
        save_checkpoint(best_path(ckpt), st, kind, cfg, obs_names=names)
    lanes = env.get_state() if not finished and hasattr(env, "get_state") else None
    run = None if lanes is None else {"env": lanes, "obs": torch.from_numpy(obs.copy()),
                                      "acc": torch.from_numpy(acc.copy()), "ep_returns": list(ep_returns)}
    save_checkpoint(ckpt, st, kind, cfg, run, names)


NO_BEST = {"level": -math.inf, "steps": 0}   # no best policy saved yet


def next_best(best: dict, level: float, steps: int) -> dict | None:
    """The best-policy record after a checkpoint whose window has mean training level `level`; None if the best
    stays. [facts] The highest window wins. [ours] Until a window beats the run's first one, a new lowest window
    takes the best instead: lanes that start spread up to the score's level (Preset.ppo_start "task") give the
    untrained first windows a high level that the curriculum then pulls down, and the plain rule keeps that
    untrained policy (docs/ppo_protocol "The best policy"). The same holds for a warm start (a GES round), whose lanes carry
    levels earned on other designs. A run whose level ever beats its first window keeps the plain rule's best
    exactly; a record without "first" (an older checkpoint's) keeps the plain rule."""
    if best["level"] == -math.inf:   # the run's first window
        return {"level": level, "steps": steps, "first": level, "low": level}
    if best["level"] <= best.get("first", -math.inf) and level < best["low"]:
        return {**best, "level": level, "steps": steps, "low": level}
    if level > best["level"]:
        return {**best, "level": level, "steps": steps}
    return None


def save_checkpoint(path, st: TrainState, kind, cfg, run=None, obs_names=None):
    """Atomic write (tmp + replace): a run killed while saving keeps its previous checkpoint. `run`: what an
    unfinished run needs to go on exactly (see checkpoint); a finished run's checkpoint holds none.
    `obs_names`: the env's names of the observation entries, if it has them (a policy must not run on another
    observation)."""
    state = {"version": CKPT_VERSION, "kind": kind, "obs_dim": int(st.norm.mean.shape[0]),
             "act_dim": int(st.policy.log_std.shape[0]), "cfg": {k: list(v) if isinstance(v, tuple) else v
                                                                 for k, v in asdict(cfg).items()},
             "policy": st.policy.state_dict(), "optimizer": st.opt.state_dict(), "norm": st.norm.state(),
             "steps": int(st.steps), "lr": float(st.lr), "levels": torch.as_tensor(np.asarray(st.levels)),
             "rng": st.rng.bit_generator.state, "torch_rng": torch.get_rng_state(), "extra": {"best": st.best},
             "ret_norm": st.ret_norm.state()}
    if run is not None:
        state["run"] = run
    if obs_names is not None:
        state["obs_names"] = list(obs_names)
    with atomic(path, "wb") as fh:
        torch.save(state, fh)


def best_path(ckpt: str) -> str:
    """Where train() keeps the best policy of the run checkpointed at `ckpt`: policy.pt -> policy_best.pt."""
    root, ext = os.path.splitext(ckpt)
    return f"{root}_best{ext or '.pt'}"


def scored_path(ckpt: str, rule: str = "best") -> str:
    """The checkpoint of a run that its score uses. rule='best' [facts]: the policy of the best training level
    (the authors score model_best.pt: the update with the highest mean curriculum level); a run trained
    before train() kept one falls back to its last checkpoint. rule='last' [ours, an option]: the last one."""
    if rule not in ("best", "last"):
        raise ValueError(f"rule={rule!r} must be 'best' or 'last'")
    best = best_path(ckpt)
    return best if rule == "best" and os.path.exists(best) else ckpt


def load_checkpoint(path) -> dict:
    """torch.load(weights_only=True) with a one-line error for a missing, damaged or foreign file (torch's own
    message is not shown: for a pickle it advises weights_only=False, which a user must not follow). It reads
    empty bytes too (add_safe_globals at CKPT_VERSION)."""
    if not os.path.exists(path):
        raise FileNotFoundError(f"checkpoint {path!r} does not exist")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception:
        raise ValueError(f"checkpoint {path!r} is truncated, damaged or not a ppo.py checkpoint; delete it to "
                         f"train again") from None
    if not isinstance(state, dict) or state.get("version") != CKPT_VERSION:
        raise ValueError(f"checkpoint {path!r} is not a ppo.py checkpoint of version {CKPT_VERSION}")
    return state


def config_from(state) -> PPOConfig:
    return PPOConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in state["cfg"].items()})


def policy_from(state) -> tuple[nn.Module, RunningNorm]:
    """Rebuild the actor-critic and its observation normaliser from a checkpoint state."""
    cfg = config_from(state)
    policy = make_policy(state["kind"], state["obs_dim"], state["act_dim"], cfg)
    try:
        policy.load_state_dict(state["policy"])
    except RuntimeError as e:
        raise ValueError(f"checkpoint does not match a {state['kind']} policy: {e}") from None
    norm = RunningNorm(state["obs_dim"], cfg.obs_clip)
    norm.load(state["norm"])
    return policy, norm


def checked_policy(state, path, kind, env) -> tuple[nn.Module, RunningNorm]:
    """The policy and normaliser of checkpoint `state` (read from `path`) for a `kind` run on `env`; a checkpoint
    of another policy kind, size or observation is a clear error."""
    names = obs_names_of(env)
    if (state["obs_dim"], state["act_dim"]) != (env.obs_dim, env.act_dim) or state["kind"] != kind:
        raise ValueError(f"checkpoint {path!r} holds a {state['kind']} policy for obs {state['obs_dim']} /"
                         f" act {state['act_dim']}, not a {kind} policy for obs {env.obs_dim} / act {env.act_dim}")
    if state.get("obs_names", names) != names:   # (older files: checkpoints older than the names are checked by size)
        raise ValueError(f"checkpoint {path!r} holds a policy that observed {state['obs_names']}, this env "
                         f"observes {names}")
    return policy_from(state)


def resume_from(st: TrainState, state: dict, env, own: bool):
    """start_run's resume half: a checkpoint's optimiser, return statistics, curriculum levels, learning rate and
    step count go on in the run `st` (a warm start: a GES round); if `own` (the run resumes its own checkpoint),
    its best-policy record and random streams too, and the whole state as `st.own` (for resume_env)."""
    st.opt.load_state_dict(state["optimizer"])
    if "ret_norm" in state:   # (older files: none before cfg.reward_norm)
        st.ret_norm.load(state["ret_norm"])
    if len(state["levels"]):
        st.levels = np.resize(state["levels"].numpy(), env.num_envs)
    st.lr, st.steps = state["lr"], state["steps"]
    if own:   # resuming this very run: continue its random streams too
        st.own, st.best = state, state["extra"].get("best", NO_BEST)   # (older files: no best record)
        st.rng.bit_generator.state = state["rng"]
        torch.set_rng_state(state["torch_rng"])


def resume_env(env, own, design_sampler, progress):
    """Put `env` back where the resumed run's checkpoint `own` left it and return the last observations; None
    where the run starts fresh episodes instead: no checkpoint of its own, one without the env's state (a
    finished run's, an older one's), or an env of other lanes (said in a progress line)."""
    run = own.get("run") if own else None
    if run is None or not hasattr(env, "set_state"):
        return None
    try:
        env.set_design_sampler(design_sampler)
        env.set_state(run["env"])
    except ValueError as e:
        if progress:
            progress(f"resumed at {own['steps']:,} steps with fresh episodes: {e}")
        return None
    if progress:
        progress(f"resumed exactly at {own['steps']:,} steps (each lane's episode so far replayed)")
    return run["obs"].numpy().copy()


def obs_names_of(env):
    """The names of the env's observation entries as a list (a checkpoint keeps them), None if it has none."""
    names = getattr(env, "obs_names", None)
    return list(names) if names else None


# ----------------------------------------------------------------------------------------------------------
# 8. A checkpoint as a plain callable
# ----------------------------------------------------------------------------------------------------------
class PolicyFn:
    """obs (n, obs_dim) numpy -> deterministic action (the Gaussian mean), as ballu.score expects.

    Row by row [ours]: a batched matrix product rounds a row differently for other batch sizes (measured: 33 of
    400 sub-batches of a random MLP differ from the full batch), and contact physics turns rounding into other
    trajectories. So a design's J must not depend on which designs share its call, or on the worker count.
    Costs ~27 us per row, ~2 % of the physics of a 20 Hz step. Being pure (no state, rows
    independent), it lets ballu.score play each level of a walk once (`reuse`)."""
    pure = True

    def __init__(self, policy: nn.Module, norm: RunningNorm, cfg: PPOConfig = PPOConfig(), obs_names=None):
        self.policy, self.norm, self.cfg = policy.eval(), norm, cfg
        self.obs_names = obs_names   # what it observed in training, if its checkpoint says (ballu.policy_config checks)
        self.obs_dim = len(norm.mean)   # how many entries it observed (checked where the names are not kept)

    def __call__(self, obs):
        x = torch.from_numpy(self.norm(np.asarray(obs)))
        with torch.inference_mode():
            mu = np.concatenate([self.policy.mean(x[i:i + 1]).numpy() for i in range(len(x))])
        return to_env(mu.astype(np.float64), self.cfg)

    def gate_weights(self, design_obs):
        """MoE gate weights for raw design-vector observations (n, design_dim), normalised as in training."""
        x = self.norm(design_obs, slice(-self.policy.design_dim, None))
        with torch.no_grad():
            return self.policy.gate_weights(torch.from_numpy(x)).numpy()


def load_policy(path: str) -> PolicyFn:
    torch.set_num_threads(1)
    state = load_checkpoint(path)
    return PolicyFn(*policy_from(state), config_from(state), state.get("obs_names"))


# ----------------------------------------------------------------------------------------------------------
# 9. Benchmark: end-to-end training against the env alone
# ----------------------------------------------------------------------------------------------------------
def _random_steps(env, T, mean, std, seed):
    """The env-only reference: T steps with N(mean, std) actions, run where the env lives (no policy)."""
    rng = np.random.default_rng(seed)
    for _ in range(T):
        env.step(rng.normal(mean, std, (env.num_envs, env.act_dim)))


def bench(make_env, cfg: PPOConfig = PPOConfig(), workers: int = 2, iters: int = 30):
    """Env-only control steps/s (fixed random policy) vs end-to-end PPO training, same env layout.

    A machine's speed can drift within minutes, so the two are measured in alternation: after every PPO
    iteration (rollout + GAE + update + checkpoint, timed between iterations) a second, identical env steps
    the same number of control steps with random actions, each worker stepping its own lanes with no round
    trip to this process (the fastest the env can be stepped; the difference is the policy and the update
    alone). The ratio is the median over these pairs."""
    import tempfile
    env, ref = make_env(cfg.num_envs, workers), make_env(cfg.num_envs, workers)
    ref.reset(seed=0)
    n, pairs, mark = cfg.num_steps * cfg.num_envs, [], [0.0]

    def env_only_chunk(_msg):
        train_s = time.time() - mark[0]
        t0 = time.time()
        args = (cfg.num_steps, cfg.init_action_mean, cfg.init_std, len(pairs))
        if hasattr(ref, "run"):
            ref.run(_random_steps, [args] * len(ref.parts))
        else:
            _random_steps(ref, *args)
        pairs.append((n / (time.time() - t0), n / train_s))
        mark[0] = time.time()

    try:
        with tempfile.TemporaryDirectory() as d:
            mark[0] = time.time()
            train("mlp", env, None, n * (iters + 1), os.path.join(d, "p.pt"), cfg, progress=env_only_chunk)
    finally:
        env.close()
        ref.close()
    env_rate, train_rate = np.array(pairs[1:]).T   # the first iteration also holds the env reset
    ratio = train_rate / env_rate
    print(f"env only (random policy): {np.median(env_rate):8.0f} control steps/s   ({cfg.num_envs} envs, "
          f"{workers} workers; median of {len(ratio)} chunks of {n} steps)")
    print(f"PPO training end to end : {np.median(train_rate):8.0f} control steps/s   (median per-pair ratio "
          f"{100 * np.median(ratio):.0f} % of env only; quartiles {100 * np.quantile(ratio, 0.25):.0f}-"
          f"{100 * np.quantile(ratio, 0.75):.0f} %)")
    return float(np.median(env_rate)), float(np.median(train_rate)), float(np.median(ratio))


COMMANDS = """ppo.py -- PPO from scratch in torch; its command line times it (train on BALLU: run_all.py, ppo_ballu).

    python ppo.py bench [--envs 32] [--workers 2] [--iters 30] [--env ballu]
"""


def _main(argv=None):
    """`python ppo.py bench`: PPO's own cost on a batched env, next to stepping that env alone. The env comes
    from a module named on the command line (default: ballu, the robot of the paper), which must offer
    make_env(num_envs, workers); this module imports no env of its own."""
    import importlib
    from runkit import args
    ap = args.program("python ppo.py", COMMANDS)
    sub = ap.add_subparsers(dest="cmd", required=True)
    b = args.command(sub, "bench", "env-only vs end-to-end training rate", COMMANDS)
    b.add_argument("--env", default="ballu", help="module offering make_env(num_envs, workers) (default ballu)")
    args.add_workers(b, "env worker processes, 1..--envs")
    b.add_argument("--envs", type=int, default=PPOConfig.num_envs, help="lanes in all (>= 1)")
    b.add_argument("--iters", type=int, default=30, help="PPO iterations timed (>= 2)")
    a = args.parse(ap, argv, {"--bench": ("bench", False)})
    for opt, value, ok in (("--envs", a.envs, a.envs >= 1), ("--iters", a.iters, a.iters >= 2),
                           ("--workers", a.workers, 1 <= a.workers <= a.envs)):
        if not ok:
            ap.error(f"{opt} {value} must be " + {"--envs": ">= 1", "--iters": ">= 2"}.get(opt, "in [1, --envs]"))
    try:
        make_env = importlib.import_module(a.env).make_env
    except (ImportError, AttributeError) as e:
        ap.error(f"--env {a.env}: not a module offering make_env(num_envs, workers) ({e})")
    bench(make_env, PPOConfig(num_envs=a.envs), a.workers, a.iters)
    return 0


if __name__ == "__main__":
    raise SystemExit(_main())
