"""Gaussian Evolutionary Specialists (GES) in one readable file: Alg. 1 and Sec. IV ("Gaussian Evolutionary
Specialists") of the paper "Rapid co-design of Buoyancy-assisted robots for Challenging Locomotion using Gaussian
Evolutionary Specialists" (Sinha, Sontakke, Hong, Tanaka and Ha).

GES keeps K specialists, each owning a diagonal Gaussian "territory" over the design space. Every round it
  1. trains each specialist on designs drawn from its territory (warm-started from its last checkpoint),
  2. probes F designs near the territories' 2-sigma borders; every specialist scores every probe and the best
     scorer wins it (eq. 6),
  3. refits each Gaussian to the designs it holds (eq. 7),
and stops when the territories cover 95 % of the design space (eqs. 8-9). Afterwards a density router (eq. 10)
hands any design to one specialist, so an outer search (TPE) scores designs without training.

Equation numbers count the paper's numbered equations in order:
  (5) space-filling objective of the initialisation, (6) probe argmax, (7) refit, (8) unnormalised f_k,
  (9) MC coverage c-hat, (10) density router. Alg. 1's lines: 1-5 initialisation, 6-19 the loop (Train 7-10,
  Probe 11-15, Refit 16, CheckCoverage 17; the paper's text calls it 18). Provenance of every choice is marked in
  its docstring: [paper], [facts] (docs/facts.md, the authors' code read as facts) or [ours] (the paper and the
  facts are silent).

This module knows nothing about BALLU or PPO. It takes two plain callables (picklable, so that the K
specialists can run in a process pool):

    train_fn(k, round, sampler, ckpt_in, ckpt_out) -> None
        k        int, the specialist's index 0..K-1
        round    int, the GES round 0, 1, ... (the round being trained)
        sampler  GaussianSampler: sampler(rng, n) -> (n, d) designs in PHYSICAL units drawn from the
                 specialist's territory (clipped to the box). sampler.seed is an int derived from
                 (seed, round, k): seed the trainer's own RNGs (torch, env) with it for reproducibility.
        ckpt_in  str | None, the checkpoint written by this specialist's previous round (None in round 0)
        ckpt_out str, a file path inside run_dir that the trainer MUST write (overwrite if it exists: a resumed
                 run repeats an interrupted round). Its format is the trainer's business.
    score_fn(k, ckpt, designs) -> (n,) array of scores, higher is better
        designs  (n, d) float array in PHYSICAL units. Must be deterministic for exact reproducibility.
                 Each design's score must not depend on the call's other designs.

Read top to bottom: 1. settings and randomness, 2. territories (f_k, coverage, router, refit, probes),
3. initialisation and the run's state, 4. the GES loop (Alg. 1), 5. the routed evaluator; then the machinery:
6. settings' checks, state files, history, result, 7. executors, 8. adaptive K (ours: merge a specialist another
serves as well, split a territory its specialist serves unevenly), 9. the command line (experiments/ges_demo.py).

Entry points: run_ges(...) -> GESResult, load_result(run_dir), routed_evaluator(result, score_fn); the figure of
a run's territories: report.figures.plot_territories. `python ges.py demo --out OUT` runs a synthetic landscape
(`--K auto --sites B`: adaptive K on B planted sites), `sweep` prints rounds to coverage per (n_init, F), `bench`.
"""
from __future__ import annotations

import json
import math
import os
import sys
import time
from concurrent.futures import Executor, ProcessPoolExecutor, wait
from dataclasses import asdict, dataclass, field, replace
from functools import partial
from typing import Callable

import numpy as np

from runkit import settings   # need, integer: a setting's one-line ValueError
from runkit.box import Box   # the design box: names, bounds, the unit cube [paper, Sec. IV-B]
from runkit.files import write_json   # atomic: a crash never leaves half a state file
from runkit.pool import SerialExecutor   # runs each task inline: for debugging and tests

# ---------------------------------------------------------------------------------------------------------
# 1. Settings and randomness
# ---------------------------------------------------------------------------------------------------------
INIT_METHODS = ("grid", "random", "fps", "fps+lloyd")
ROUTERS = ("density", "oracle")


@dataclass
class GESConfig:
    """GES settings. Every default is the paper's or the facts' value (source in the comment)."""
    K: int = 3                        # specialists: 3 in D2, 6 in D3 [facts; paper Sec. V]
    n_probe: int = 100                # F probes per round [facts; paper Alg. 1 names F]
    probe_pool: int = 2000            # uniform points the probes are picked from [facts]
    band_lo: float = -2.5             # probe band on max_k log f_k (eq. 8): -2.5 < . < -0.5, i.e. Mahalanobis
    band_hi: float = -0.5             #   distance 1..2.24 around the 2-sigma border [facts]
    n_init_designs: int = 50          # designs per specialist seeding eta_k [facts]
    n_mc: int = 10_000                # N_mc MC coverage points [paper, Sec. V-A]
    tau: float = math.exp(-2)         # coverage threshold on f_k, the 2-sigma contour [paper, eq. 8]
    target_coverage: float = 0.95     # stop criterion [paper, Sec. IV-B]
    init_coverage: float = 0.12       # sigma_0 calibrated to this MC coverage [paper, Sec. V-A]
    max_rounds: int = 20              # hard stop [facts]
    lloyd_iters: int = 12             # T Lloyd iterations [facts; paper Sec. IV-B names T]
    fps_pool: int = 10_000            # uniform pool for FPS and Lloyd [facts]
    var_floor: float = 1e-4           # per-axis variance floor (1 % of the range)^2 in unit coords [facts]
    init: str = "fps+lloyd"           # centre initialisation [paper, Sec. IV-B and Table III]
    router: str = "density"           # outer-loop router: 'density' [paper, eq. 10] or 'oracle' [facts, QUIRK]
    # Adaptive K [ours; the paper's Sec. VI names it as open, its runs fix K]: K above is then the start, and
    # between rounds a redundant specialist is merged, a territory its specialist serves unevenly is split
    # (section 8 below; study: docs/ges_adaptive).
    adaptive: bool = False            # False: the paper's fixed K
    K_min: int = 1                    # bounds of the adaptive K
    K_max: int = 8
    n_check: int = 16                 # designs drawn from each territory, scored by every specialist, per round
    merge_tol: float = 0.05           # merge j if another loses <= this share of the scale on j's checks, per design
    split_gap: float = 0.25           # challenge k if its checks' two 2-means halves differ by this share
    split_cooldown: int = 2           # rounds a territory that absorbed another waits before it may split,
                                      #   doubled for each challenger of its own it took back (backoff)
    challenge_rounds: int = 2         # rounds a specialist (the first K, a challenger) trains before a merge test
    # [ours] after the loop, one more Train on the final territories, the ones the router hands designs to: the
    # loop never trains on the last refit's (an option for the schedule screen, docs/ges_schedule)
    final_train: bool = False

    def __post_init__(self):
        _check_config(self)   # section 6: one ValueError naming the setting and what is allowed


# Every draw comes from a generator derived from (seed, stream, round, k), so results do not depend on the
# order in which specialists run [ours]. The project's one seed derivation: a run names its consumers through it
# too (codesign.policies.derive_seed).
INIT, INIT_DESIGNS, COVERAGE, TRAIN, PROBE, CHECK = range(6)  # stream ids


def rng_for(seed: int, *keys: int) -> np.random.Generator:
    """The generator of stream `keys` of `seed` (numpy's SeedSequence of [seed, *keys])."""
    return np.random.default_rng(np.random.SeedSequence([seed, *keys]))


def seed_for(seed: int, *keys: int) -> int:
    """An integer seed for stream `keys` of `seed`, for a consumer that seeds its own generators (a trainer)."""
    return int(np.random.SeedSequence([seed, *keys]).generate_state(1)[0])


def mc_points(seed: int, n: int, d: int) -> np.ndarray:
    """The N_mc uniform points of eq. 9. The same points every round (common random numbers), so the coverage
    history is not jittered by MC noise [ours]."""
    return rng_for(seed, COVERAGE).random((n, d))


# ---------------------------------------------------------------------------------------------------------
# 2. Gaussian territories in the unit cube [paper, Sec. IV-B: "normalized design space"]: f_k, coverage,
#    density, router, refit, and the designs drawn from them
# ---------------------------------------------------------------------------------------------------------
def log_f(x: np.ndarray, mu: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """log f_k(x) = -sum_d (x_d - mu_kd)^2 / (2 sigma_kd^2), the unnormalised density of eq. 8. (n, K)."""
    z = (x[:, None, :] - mu[None, :, :]) / sigma[None, :, :]
    return -0.5 * np.einsum("nkd,nkd->nk", z, z)


def coverage(mu: np.ndarray, sigma: np.ndarray, points: np.ndarray, tau: float = math.exp(-2)) -> float:
    """MC coverage c-hat (eq. 9): fraction of points with max_k f_k > tau (eq. 8; tau = e^-2 is the 2-sigma
    contour)."""
    return float(np.mean(log_f(points, mu, sigma).max(axis=1) > math.log(tau)))


def log_density(x: np.ndarray, mu: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """log N(x | mu_k, diag sigma_k^2), normalised (determinant included), in log space. (n, K)."""
    d = mu.shape[1]
    return log_f(x, mu, sigma) - np.log(sigma).sum(axis=1)[None, :] - 0.5 * d * math.log(2 * math.pi)


def route_unit(x: np.ndarray, mu: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Density router [paper, eq. 10] on unit designs x (GESResult.route takes physical ones): k* = argmax_k
    N(x | mu_k, Sigma_k), ties to the lower index. The argmax is the same in unit and physical coordinates (the
    Jacobian is common to all k)."""
    return np.argmax(log_density(np.atleast_2d(x), mu, sigma), axis=1)


def refit(eta: np.ndarray, var_floor: float = 1e-4) -> tuple[np.ndarray, np.ndarray]:
    """Refit [paper, eq. 7]: mu = mean(eta), Sigma = diagcov(eta), with the variance floored at var_floor
    [facts] so a territory never collapses to a line. Population variance (ddof=0, numpy's default; ours)."""
    return eta.mean(axis=0), np.sqrt(np.maximum(eta.var(axis=0), var_floor))


def refit_all(eta: list, var_floor: float) -> tuple[np.ndarray, np.ndarray]:
    """eq. 7 for every k: (K, d) centres and standard deviations of the designs eta_k each specialist holds."""
    fits = [refit(e, var_floor) for e in eta]
    return np.stack([f[0] for f in fits]), np.stack([f[1] for f in fits])


def sample_clipped(mu: np.ndarray, sigma: np.ndarray, rng: np.random.Generator, n: int) -> np.ndarray:
    """n draws from N(mu, diag sigma^2) clipped to the unit box [facts: 'clipped to the box']."""
    return np.clip(mu + sigma * rng.standard_normal((n, len(mu))), 0.0, 1.0)


def sample_probes(mu: np.ndarray, sigma: np.ndarray, rng: np.random.Generator, n_probe: int = 100,
                  pool_size: int = 2000, band: tuple = (-2.5, -0.5)) -> np.ndarray:
    """Border probes [paper, Alg. 1 SampleBorder; facts]: pool_size uniform points, keep those whose
    g = max_k log f_k lies in the band and take the n_probe OUTERMOST of them (lowest g first; this order and
    the top-up are the authors' code, not in the facts file; why: docs/choices.md). If fewer than
    n_probe lie in the band, top up with the out-of-band points of lowest g, i.e. farthest from every territory.
    Returns (n_probe, d) unit points."""
    pool = rng.random((pool_size, mu.shape[1]))
    g = log_f(pool, mu, sigma).max(axis=1)
    in_band = (g > band[0]) & (g < band[1])
    order = np.lexsort((g, ~in_band))  # in-band first, then by g ascending
    return pool[order[:n_probe]]


@dataclass(eq=False)
class GaussianSampler:
    """A specialist's territory as handed to train_fn: sampler(rng, n) -> (n, d) PHYSICAL designs drawn from
    N(mu, diag sigma^2) in unit coordinates, clipped to the box. Picklable. `seed` (derived from
    (seed, round, k)) is for the trainer's own RNGs."""
    mu: np.ndarray      # (d,) unit
    sigma: np.ndarray   # (d,) unit
    space: Box
    seed: int = 0

    def __call__(self, rng: np.random.Generator, n: int) -> np.ndarray:
        x = self.space.from_unit(sample_clipped(self.mu, self.sigma, rng, n))
        return np.clip(x, self.space.lo, self.space.hi)  # no ulp past the bounds


# ---------------------------------------------------------------------------------------------------------
# 3. Initialisation [paper, Sec. IV-B, Table III; facts]: centres, sigma_0, initial designs; the run's state
# ---------------------------------------------------------------------------------------------------------
def farthest_point_sampling(pool: np.ndarray, K: int, rng: np.random.Generator) -> np.ndarray:
    """FPS [paper]: start at a random pool point, then repeatedly add the pool point farthest from the
    centres chosen so far. Greedy 2-approximation of the min-max objective eq. 5."""
    chosen = [int(rng.integers(len(pool)))]
    dist = np.linalg.norm(pool - pool[chosen[0]], axis=1)
    for _ in range(K - 1):
        chosen.append(int(np.argmax(dist)))
        dist = np.minimum(dist, np.linalg.norm(pool - pool[chosen[-1]], axis=1))
    return pool[chosen].copy()


def lloyd(centers: np.ndarray, pool: np.ndarray, iters: int) -> np.ndarray:
    """Lloyd relaxation [paper]: move each centre to the centroid of its Voronoi cell of the pool. FPS picks
    the box's corners and edges; Lloyd pulls the centres in so they tile the box evenly. An empty cell keeps
    its centre [ours]."""
    c = centers.copy()
    for _ in range(iters):
        owner = np.argmin(((pool[:, None, :] - c[None]) ** 2).sum(-1), axis=1)
        for k in range(len(c)):
            if np.any(owner == k):
                c[k] = pool[owner == k].mean(axis=0)
    return c


def grid_centers(K: int, d: int) -> np.ndarray:
    """Grid baseline of Table III (details ours): cell centres of the smallest m^d grid with m^d >= K, first
    K in lexicographic order. Unbalanced when K is not m^d, as the paper notes for odd K."""
    m = 1
    while m ** d < K:
        m += 1
    cells = np.stack(np.meshgrid(*[np.arange(m)] * d, indexing="ij"), axis=-1).reshape(-1, d)
    return (cells[:K] + 0.5) / m


def init_centers(method: str, K: int, d: int, rng: np.random.Generator, pool_size: int = 10_000,
                 lloyd_iters: int = 12) -> np.ndarray:
    """K centres in [0,1]^d by 'grid', 'random', 'fps' or 'fps+lloyd' (paper's default; pool of 10,000
    uniform points and 12 Lloyd iterations per the facts)."""
    if method not in INIT_METHODS:
        raise ValueError(f"method={method!r} not allowed: one of {INIT_METHODS}")
    if K < 1 or d < 1:
        raise ValueError(f"K={K} and d={d} must both be >= 1")
    if method == "grid":
        return grid_centers(K, d)
    if method == "random":
        return rng.random((K, d))
    pool = rng.random((pool_size, d))
    c = farthest_point_sampling(pool, K, rng)
    return lloyd(c, pool, lloyd_iters) if method == "fps+lloyd" else c


def calibrate_sigma(mu: np.ndarray, points: np.ndarray, target: float = 0.12, tau: float = math.exp(-2),
                    iters: int = 60) -> np.ndarray:
    """sigma_0 [facts]: isotropic per unit axis, proportional to 1/K^(1/d) (range/K^(1/d) in physical units),
    scaled by bisection until the MC coverage (eq. 9, on `points`) reaches `target` (12 %, paper Sec. V-A).
    Coverage is monotone in the scale, so bisection returns the smallest scale reaching the target."""
    K, d = mu.shape
    base = np.full((K, d), K ** (-1.0 / d))
    lo, hi = 0.0, 1.0
    while coverage(mu, hi * base, points, tau) < target:
        hi *= 2.0
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if coverage(mu, mid * base, points, tau) >= target else (mid, hi)
    return hi * base


@dataclass
class GESState:
    """Where a run stands after `round` completed rounds (0: the initialisation), in unit coordinates. Saved as
    state.json after every round (section 6), so a run resumes where it stopped."""
    round: int
    mu_unit: np.ndarray       # (K, d) territory centres, unit coordinates (GESResult.mu: physical)
    sigma_unit: np.ndarray    # (K, d) territory standard deviations (diagonal Sigma_k), unit coordinates
    eta: list                 # eta_k: the (n_k, d) designs specialist k holds (its seeds and the probes it won)
    ckpt: list                # each specialist's last checkpoint, relative to run_dir (None before round 0)
    done: bool                # covered (or at the round cap): the loop ends
    history: list             # history.json's rounds (section 6)
    ids: list                 # each specialist's id: its index with a fixed K (adaptive K retires some)
    adapt: dict | None = None     # adaptive K's bookkeeping (section 8): wait, next_id, born, parent, strikes
    task_seconds: list = field(default_factory=list)   # per round, each train and probe task's own seconds
    final_trained: bool = False   # the final territories trained on (GESConfig.final_train)

    @property
    def K(self) -> int:
        return len(self.mu_unit)


def initial_state(space: Box, config: GESConfig, seed: int, points: np.ndarray) -> GESState:
    """Alg. 1 lines 1-5: centres (eq. 5 approximation), sigma_0 at 12 % coverage, 50 designs per eta_k. The
    start depends on the space, the config and the seed only, never on the task [ours]: two tasks on one space
    start from the same mu, sigma and eta_k, so their runs differ only by what the task teaches."""
    mu = init_centers(config.init, config.K, space.d, rng_for(seed, INIT), config.fps_pool, config.lloyd_iters)
    sigma = calibrate_sigma(mu, points, config.init_coverage, config.tau)
    eta = [sample_clipped(mu[k], sigma[k], rng_for(seed, INIT_DESIGNS, k), config.n_init_designs)
           for k in range(config.K)]
    ids = list(range(config.K))   # adaptive K: a specialist's id names it while others come and go (section 8)
    born = {str(k): 0 for k in ids}   # adaptive K judges the first K like challengers born in round 0
    adapt = dict(wait={}, next_id=config.K, born=born) if config.adaptive else None
    state = GESState(0, mu, sigma, eta, [None] * config.K, False, [], ids, adapt)
    state.history = [history_entry(space, state, coverage(mu, sigma, points, config.tau), np.zeros((0, space.d)),
                                   np.zeros(0, int), ids, [] if config.adaptive else None)]
    return state


# ---------------------------------------------------------------------------------------------------------
# 4. The GES loop [paper, Alg. 1]
# ---------------------------------------------------------------------------------------------------------
def ges_round(space, train_fn, score_fn, run_dir, config, seed, executor, state: GESState, points) -> GESState:
    """One pass of Alg. 1's loop (the body of lines 6-19): Train, Probe (eq. 6), Refit (eq. 7), CheckCoverage
    (eqs. 8-9); then adapt_k, which with config.adaptive merges and splits (section 8). Returns the
    next state; `state` is not modified. A specialist is named by its id (its index with a fixed K): its seeds
    and checkpoint files follow it when others are merged away."""
    t, K, ids = state.round, state.K, state.ids
    ckpt, train_s = train(space, train_fn, run_dir, seed, executor, state)   # Train (Alg. 1 lines 7-10)
    # Probe (lines 11-15, eq. 6): F designs near the 2-sigma borders; every specialist scores every one and the
    # best scorer wins it, ties to the lower index [facts].
    probes = sample_probes(state.mu_unit, state.sigma_unit, rng_for(seed, PROBE, t), config.n_probe, config.probe_pool,
                           (config.band_lo, config.band_hi))
    scores, probe_s = score_all(executor, score_fn, run_dir, ids, ckpt, space.from_unit(probes))
    winner = np.argmax(scores, axis=0)
    eta = [np.vstack([state.eta[k], probes[winner == k]]) for k in range(K)]
    # Refit (line 16, eq. 7): each territory to all the designs it holds. CheckCoverage (line 17, eqs. 8-9).
    mu, sigma = refit_all(eta, config.var_floor)
    cov = coverage(mu, sigma, points, config.tau)
    new = replace(state, round=t + 1, mu_unit=mu, sigma_unit=sigma, eta=eta, ckpt=ckpt,
                  done=bool(t + 1 >= config.max_rounds or cov >= config.target_coverage),
                  task_seconds=state.task_seconds + [{"train": train_s, "probe": probe_s}])
    # config.adaptive [ours, section 8]: merge a redundant specialist, split an unevenly served territory
    new, cov, events = adapt_k(space, score_fn, run_dir, config, seed, executor, state, new, points, cov)
    entry = history_entry(space, new, cov, probes, winner, ids, events, scores)
    return replace(new, history=state.history + [entry])


def train(space, train_fn, run_dir, seed, executor, state: GESState) -> tuple[list, list]:
    """Train (Alg. 1 lines 7-10): each specialist on designs from its own territory, warm-started from its last
    checkpoint [paper]; (checkpoints, each task's seconds)."""
    samplers = [GaussianSampler(state.mu_unit[k], state.sigma_unit[k], space,
                                seed_for(seed, TRAIN, state.round, state.ids[k]))
                for k in range(state.K)]
    return train_all(executor, train_fn, run_dir, state.round, state.ids, samplers, state.ckpt)


def train_final(space, train_fn, run_dir, seed, executor, state: GESState) -> GESState:
    """GESConfig.final_train [ours]: Train once more, on the final territories, without a probe: a round trains
    on the territories it starts from, so the last refit's, which route every design (eq. 10), go untrained.
    The last history entry keeps the new checkpoints (its territories are unchanged)."""
    ckpt, train_s = train(space, train_fn, run_dir, seed, executor, state)
    last = dict(state.history[-1], ckpt=list(ckpt), final_train=True)
    return replace(state, ckpt=ckpt, final_trained=True, history=state.history[:-1] + [last],
                   task_seconds=state.task_seconds + [{"train": train_s, "probe": []}])


def run_ges(space: Box, train_fn: Callable, score_fn: Callable, run_dir: str,
            config: GESConfig | None = None, seed: int = 0, executor: Executor | None = None,
            progress: Callable[[str], None] | None = print) -> GESResult:
    """Run (or resume) GES until MC coverage >= target or max_rounds [paper, Alg. 1]. The state is saved after
    every round: a rerun on run_dir resumes there and ends with exactly an uninterrupted run's result (every draw
    derives from (seed, round, k)). executor=None: a process pool of every core; SerialExecutor() to debug."""
    config, space = config or GESConfig(), Box.of(space)
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed={seed!r} not allowed: a non-negative integer")
    say = progress or (lambda s: None)
    os.makedirs(os.path.join(run_dir, CKPT_DIR), exist_ok=True)
    points = mc_points(seed, config.n_mc, space.d)
    state = _load_state(run_dir, space, config, seed)
    if state is None:
        state = initial_state(space, config, seed, points)
        _save_state(run_dir, space, config, seed, state)
        say(f"GES init: K={config.K} d={space.d} ({config.init}), coverage {state.history[0]['coverage']:.1%}")
    elif not state.done:
        say(f"GES resume: {run_dir} after round {state.round}")
    own = executor is None and (not state.done or (config.final_train and not state.final_trained))
    executor = ProcessPoolExecutor(max_workers=os.cpu_count()) if own else executor
    start = time.time()
    try:
        while not state.done:   # Alg. 1 line 6: until covered
            state = ges_round(space, train_fn, score_fn, run_dir, config, seed, executor, state, points)
            _save_state(run_dir, space, config, seed, state)
            h = state.history[-1]
            adapt = "".join(f"  {e['kind']} {e['id']}->{e.get('into', e.get('child'))}" for e in h.get("events", []))
            say(f"round {h['round']:2d}/{config.max_rounds}  coverage {h['coverage']:6.1%}  wins {h['wins']}  "
                + (f"K {len(h['mu'])}{adapt}  " if config.adaptive else "") + f"elapsed {time.time() - start:7.1f}s")
        if config.final_train and not state.final_trained:
            state = train_final(space, train_fn, run_dir, seed, executor, state)
            _save_state(run_dir, space, config, seed, state)
            say(f"final training on the final territories  elapsed {time.time() - start:7.1f}s")
    finally:
        if own:
            executor.shutdown()
    return _result(run_dir, space, config, seed, state)


# ---------------------------------------------------------------------------------------------------------
# 5. What GES hands to the outer search: the result and its routed evaluator [paper, Sec. IV-C]
# ---------------------------------------------------------------------------------------------------------
@dataclass(eq=False)
class GESResult:
    """What GES hands to the outer search: territories (unit and physical), final checkpoints, history."""
    space: Box
    config: GESConfig
    seed: int
    run_dir: str
    mu_unit: np.ndarray      # (K, d)
    sigma_unit: np.ndarray   # (K, d)
    mu: np.ndarray           # (K, d) physical
    sigma: np.ndarray        # (K, d) physical
    ckpt: list               # absolute paths of each specialist's last checkpoint
    history: dict            # the content of history.json
    rounds: int
    coverage: float
    task_seconds: float = 0.0   # every train and probe task's own seconds, summed: GES's compute (core-s)
    ids: list = field(default_factory=list)   # each specialist's id (section 8; 0..K-1 with a fixed K)

    def route(self, theta) -> np.ndarray:
        """Density router (eq. 10) on physical designs -> specialist indices (n,)."""
        return route_unit(self.space.to_unit(self.space.validate(theta)), self.mu_unit, self.sigma_unit)


class RoutedEvaluator:
    """J(theta) for TPE: 'density' scores theta with the specialist of highest Gaussian density (paper
    eq. 10, default); 'oracle' scores it with every specialist and keeps the best (the authors' code, facts).
    theta physical, (d,) -> float or (n, d) -> (n,)."""

    def __init__(self, result: GESResult, score_fn: Callable, router: str | None = None):
        router = router or result.config.router
        if router not in ROUTERS:
            raise ValueError(f"router={router!r} not allowed: one of {ROUTERS}")
        if any(c is None for c in result.ckpt):
            raise ValueError(f"result has no trained checkpoints yet (rounds={result.rounds}); run GES first")
        self.result, self.score_fn, self.router = result, score_fn, router
        self.ids = list(result.ids) or list(range(len(result.ckpt)))   # a GESResult built by hand may not name them

    def __call__(self, theta):
        x = self.result.space.validate(theta)
        r = self.result
        if self.router == "oracle":
            out = np.max([np.asarray(self.score_fn(self.ids[k], r.ckpt[k], x), float) for k in range(len(r.ckpt))],
                         axis=0)
        else:
            ks, out = r.route(x), np.empty(len(x))
            for k in np.unique(ks):
                out[ks == k] = np.asarray(self.score_fn(self.ids[k], r.ckpt[k], x[ks == k]), float)
        return float(out[0]) if np.ndim(theta) == 1 else out


def routed_evaluator(result: GESResult, score_fn: Callable, router: str | None = None) -> RoutedEvaluator:
    """J(theta) callable of the routed specialist's score; router None -> result.config.router."""
    return RoutedEvaluator(result, score_fn, router)


# ---------------------------------------------------------------------------------------------------------
# 6. Settings' checks; state files, history, result (all JSON; floats round-trip exactly through json's repr)
# ---------------------------------------------------------------------------------------------------------
def _check_config(c: GESConfig) -> None:
    """runkit.settings' one-line ValueError for the first setting out of its range."""
    need, integer = partial(settings.need, c), partial(settings.integer, c)
    for name in ("K", "n_probe", "probe_pool", "n_init_designs", "n_mc", "max_rounds", "fps_pool"):
        integer(name, 1)
    integer("lloyd_iters", 0)
    need("probe_pool", c.probe_pool >= c.n_probe, f"an integer >= n_probe={c.n_probe}")
    need("fps_pool", c.fps_pool >= c.K, f"an integer >= K={c.K}")
    need("band_hi", c.band_hi <= 0, "<= 0 (a log of f_k <= 1)")
    need("band_lo", c.band_lo < c.band_hi, f"< band_hi={c.band_hi}")
    need("tau", 0 < c.tau < 1, "in (0, 1)")
    need("target_coverage", 0 < c.target_coverage <= 1, "in (0, 1]")
    need("init_coverage", 0 < c.init_coverage < 1, "in (0, 1)")
    need("var_floor", c.var_floor > 0, "> 0")
    need("init", c.init in INIT_METHODS, f"one of {INIT_METHODS}")
    need("router", c.router in ROUTERS, f"one of {ROUTERS}")
    need("adaptive", isinstance(c.adaptive, (bool, np.bool_)), "True or False")
    need("final_train", isinstance(c.final_train, (bool, np.bool_)), "True or False")
    for name in ("K_min", "K_max", "n_check"):
        integer(name, 1)
    need("K_max", c.K_max >= c.K_min, f"an integer >= K_min={c.K_min}")
    need("n_check", c.n_check >= 2, "an integer >= 2 (the split test halves a territory's checks)")
    need("merge_tol", 0 <= c.merge_tol < 1, "in [0, 1)")
    need("split_gap", 0 < c.split_gap < 1, "in (0, 1)")
    for name in ("split_cooldown", "challenge_rounds"):
        integer(name, 0)
    if c.adaptive:
        need("K", c.K_min <= c.K <= c.K_max, f"in [K_min, K_max] = [{c.K_min}, {c.K_max}] (adaptive K starts there)")
        need("fps_pool", c.fps_pool >= c.K_max, f"an integer >= K_max={c.K_max}")


STATE_FILE, HISTORY_FILE, CKPT_DIR = "state.json", "history.json", "ckpt"


def ckpt_path(i: int, t: int) -> str:
    """Specialist i's round-t checkpoint, relative to run_dir: the one name its trainer writes and readers find."""
    return os.path.join(CKPT_DIR, f"spec{i}_round{t:02d}.ckpt")


def history_entry(space, state: GESState, cov: float, probes, winner, trained: list, events: list | None,
                  scores=None) -> dict:
    """Entry r (completed rounds; 0 = initialisation): the territories after refit r, round r-1's probes, their
    winners (indices into `trained`) and every trained specialist's score of each (`probe_scores`: ties too), and
    the round's checkpoints; adaptive K adds the ids, merges and splits."""
    entry = {"round": state.round, "coverage": cov, "mu_unit": state.mu_unit.tolist(),
             "sigma_unit": state.sigma_unit.tolist(),
             "mu": space.from_unit(state.mu_unit).tolist(), "sigma": space.from_unit_scale(state.sigma_unit).tolist(),
             "wins": [int(w) for w in np.bincount(winner, minlength=len(trained))],
             "n_designs": [len(e) for e in state.eta],
             "probes_unit": np.asarray(probes).tolist(), "winner": [int(w) for w in winner],
             "probe_scores": [] if scores is None else np.asarray(scores, float).tolist(), "ckpt": list(state.ckpt)}
    if events is not None:
        entry.update(ids_trained=list(trained), ids=list(state.ids), events=events)
    return entry


def _history_doc(space, config, seed, entries) -> dict:
    return {"space": space.to_dict(), "config": asdict(config), "seed": seed, "rounds": entries}


def _state_doc(state: GESState) -> dict:
    """state.json's fields, in the order earlier versions wrote them (the initialisation's differs)."""
    doc = {"round": state.round, "mu": state.mu_unit.tolist(), "sigma": state.sigma_unit.tolist(),
           "eta": [e.tolist() for e in state.eta], "ckpt": list(state.ckpt), "done": state.done}
    adapt = {} if state.adapt is None else {"ids": list(state.ids), **state.adapt}
    if state.round == 0:
        return {**doc, "history": state.history, **adapt}
    return {**doc, **adapt, "history": state.history, "task_seconds": state.task_seconds,
            **({"final": True} if state.final_trained else {})}


def _state_of(doc: dict) -> GESState:
    mu = np.array(doc["mu"], dtype=float)
    adapt = {k: doc[k] for k in ("wait", "next_id", "born", "parent", "strikes") if k in doc}
    return GESState(doc["round"], mu, np.array(doc["sigma"], dtype=float),
                    [np.array(e, dtype=float).reshape(-1, mu.shape[1]) for e in doc["eta"]], list(doc["ckpt"]),
                    doc["done"], doc["history"], list(doc.get("ids", range(len(mu)))),
                    adapt if "ids" in doc else None, doc.get("task_seconds", []), doc.get("final", False))


def _read_state(run_dir: str) -> tuple[dict, GESState]:
    """state.json of run_dir, checked: ValueError naming the file and what to do if it is truncated, garbage or
    not a GES state, instead of a JSON / Unicode / KeyError traceback."""
    path = os.path.join(run_dir, STATE_FILE)
    try:
        with open(path) as fh:
            doc = json.load(fh)
        Box.from_dict(doc["space"]), GESConfig(**doc["config"])
        state = _state_of(doc)
        state.history[-1]["coverage"], doc["seed"]
    except (ValueError, KeyError, TypeError, AttributeError, IndexError) as e:
        raise ValueError(f"{path} is not a readable GES state ({type(e).__name__}); delete {run_dir} to start "
                         f"that GES run over") from None
    return doc, state


def _load_state(run_dir: str, space: Box, config: GESConfig, seed: int) -> GESState | None:
    if not os.path.exists(os.path.join(run_dir, STATE_FILE)):
        return None
    doc, state = _read_state(run_dir)
    for what, saved, now in (("space", Box.from_dict(doc["space"]).to_dict(), space.to_dict()),
                             ("config", asdict(GESConfig(**doc["config"])), asdict(config)),   # older: defaults
                             ("seed", doc["seed"], seed)):
        if saved != now:
            raise ValueError(f"run_dir={run_dir!r} holds a run with a different {what} ({saved} vs {now}); "
                             f"resume with the same settings or use a new run_dir")
    return state


def _save_state(run_dir, space, config, seed, state: GESState) -> None:
    """state.json and history.json, each written atomically and fsync'ed (runkit.files.write_json) [ours]."""
    write_json(os.path.join(run_dir, STATE_FILE), dict(_state_doc(state), space=space.to_dict(), config=asdict(config),
                                                       seed=seed), indent=None, durable=True)
    write_json(os.path.join(run_dir, HISTORY_FILE), _history_doc(space, config, seed, state.history), indent=None,
               durable=True)


def _result(run_dir, space, config, seed, state: GESState) -> GESResult:
    return GESResult(space, config, seed, run_dir, state.mu_unit, state.sigma_unit, space.from_unit(state.mu_unit),
                     space.from_unit_scale(state.sigma_unit),
                     [os.path.join(run_dir, c) if c else None for c in state.ckpt],
                     _history_doc(space, config, seed, state.history), state.round, state.history[-1]["coverage"],
                     float(sum(sum(r["train"]) + sum(r["probe"]) for r in state.task_seconds)), list(state.ids))


def load_result(run_dir: str) -> GESResult:
    """Rebuild the GESResult of a (finished or interrupted) run from its state.json."""
    doc, state = _read_state(run_dir)
    return _result(run_dir, Box.from_dict(doc["space"]), GESConfig(**doc["config"]), doc["seed"], state)


# ---------------------------------------------------------------------------------------------------------
# 7. Executors: the K specialists' train and probe tasks are independent [paper, Sec. V-D]
# ---------------------------------------------------------------------------------------------------------
def _timed(fn: Callable, *args) -> tuple:
    """(fn(*args), seconds), timed where the task runs: the compute a task used, not how long it queued."""
    start = time.perf_counter()
    return fn(*args), time.perf_counter() - start


def _map_all(executor: Executor, fn: Callable, arg_lists: list) -> tuple[list, list]:
    """Run fn(*args) for every args on the executor; (results, each task's seconds) in input order (never
    completion order). Waits for every task before re-raising the first failure, so no task still writes
    files after we return."""
    futures = [executor.submit(_timed, fn, *args) for args in arg_lists]
    wait(futures)
    for f in futures:
        if f.exception() is not None:
            raise f.exception()
    return [f.result()[0] for f in futures], [f.result()[1] for f in futures]


def train_all(executor, train_fn, run_dir, t, ids, samplers, ckpt_in) -> tuple[list, list]:
    """Round t's training tasks: specialist ids[k] from its checkpoint ckpt_in[k] (None in round 0) on
    samplers[k], writing ckpt_path(id, t). Returns those paths (relative to run_dir) and each task's
    seconds."""
    ckpt = [ckpt_path(i, t) for i in ids]
    _, seconds = _map_all(executor, train_fn, [(i, t, s, os.path.join(run_dir, c) if c else None,
                                                os.path.join(run_dir, out))
                                               for i, s, c, out in zip(ids, samplers, ckpt_in, ckpt)])
    for i, out in zip(ids, ckpt):
        if not os.path.exists(os.path.join(run_dir, out)):
            raise RuntimeError(f"train_fn did not write ckpt_out for specialist {i} in round {t}")
    return ckpt, seconds


def score_all(executor, score_fn, run_dir, ids, ckpt, designs) -> tuple[np.ndarray, list]:
    """(K, n) scores of every specialist on every design, one score_fn task per specialist, and each task's
    seconds."""
    scores, seconds = _map_all(executor, score_fn, [(i, os.path.join(run_dir, c), designs) for i, c in zip(ids, ckpt)])
    scores = np.stack([np.asarray(s, dtype=float).reshape(-1) for s in scores])
    if scores.shape != (len(ids), len(designs)) or np.isnan(scores).any():
        raise ValueError(f"score_fn must return {len(designs)} non-NaN scores per specialist, got shape "
                         f"{scores.shape} with {int(np.isnan(scores).sum())} NaN")
    return scores, seconds


# ---------------------------------------------------------------------------------------------------------
# 8. Adaptive K [ours]: the paper's first open direction (Sec. VI), an option beside its fixed K
# ---------------------------------------------------------------------------------------------------------
# Each round every specialist also scores n_check designs drawn from every territory ("checks"): S[i, j] holds
# specialist i's scores on territory j's checks, compared in units of the round's scale, the mean over
# territories of the owner's mean score on its own checks (scores >= 0 assumed). Why each rule below, and the
# study that measured them: docs/ges_adaptive/README.md, "The rules".
def draw_checks(space: Box, config: GESConfig, seed: int, state: GESState) -> np.ndarray:
    """The round's checks, (K, n_check, d) unit designs drawn from each territory the round started from."""
    return np.stack([sample_clipped(state.mu_unit[k], state.sigma_unit[k], rng_for(seed, CHECK, state.round, i),
                                    config.n_check)
                     for k, i in enumerate(state.ids)])


def adapt_k(space, score_fn, run_dir, config, seed, executor, state: GESState, new: GESState, points, cov) -> tuple:
    """The round's one call for adaptive K, after its refit: (new, cov, None) unchanged with a fixed K. Else the
    trained specialists score the checks drawn from the territories `state` holds (their seconds join the probe
    tasks'); merge, refit; then, unless the run is done, split and refit again. `new` is the fixed-K round's
    next state (its eta_k and checkpoints still the trained specialists'). Returns the adapted state, its
    coverage and the round's merge and split events."""
    if not config.adaptive:
        return new, cov, None
    checks = draw_checks(space, config, seed, state)
    ids, r, K, a = new.ids, new.round, new.K, new.adapt
    S, check_s = score_all(executor, score_fn, run_dir, ids, new.ckpt, space.from_unit(checks.reshape(-1, space.d)))
    S = S.reshape(K, K, checks.shape[1])
    spent = dict(new.task_seconds[-1], probe=[p + c for p, c in zip(new.task_seconds[-1]["probe"], check_s)])
    terr = {"ids": list(ids), "eta": new.eta, "ckpt": list(new.ckpt), "wait": dict(a.get("wait", {})),
            "next_id": a.get("next_id", K), "events": [], "born": dict(a.get("born", {})),
            "parent": dict(a.get("parent", {})), "strikes": dict(a.get("strikes", {}))}
    capped = r >= config.max_rounds
    terr = merge(terr, S, config, r, capped=capped)   # at the cap, no more training: the young are judged too
    mu, sigma = refit_all(terr["eta"], config.var_floor)
    cov = coverage(mu, sigma, points, config.tau)
    # the target coverage ends a run only once every split is tested (no challenger is young)
    done = bool(capped or (cov >= config.target_coverage and not young(terr, config, r)))
    if not done:   # a challenger is born only when a round will train it
        kept = [ids.index(i) for i in terr["ids"]]
        terr = split(terr, checks[kept], S[np.ix_(kept, kept)], config, r, checks.shape[2])
        mu, sigma = refit_all(terr["eta"], config.var_floor)
        cov = coverage(mu, sigma, points, config.tau)
    adapt = {k: terr[k] for k in ("wait", "next_id", "born", "parent", "strikes")}
    return (replace(new, mu_unit=mu, sigma_unit=sigma, eta=terr["eta"], ckpt=terr["ckpt"], done=done, ids=terr["ids"],
                    adapt=adapt, task_seconds=new.task_seconds[:-1] + [spent]), cov, terr["events"])


def score_scale(S: np.ndarray) -> float:
    own = np.abs(np.array([S[j, j].mean() for j in range(len(S))]))
    return max(float(own.mean()), 1e-12)


def young(terr: dict, config: GESConfig, r: int) -> set:
    """Positions of the specialists that have trained fewer than challenge_rounds rounds by round r."""
    return {k for k, i in enumerate(terr["ids"]) if r - terr["born"].get(str(i), -10 ** 6) < config.challenge_rounds}


def merge(terr: dict, S: np.ndarray, config: GESConfig, r: int, capped: bool = False) -> dict:
    """Retire each specialist whose territory another serves as well [ours; X-means' / G-means' merge-back,
    made on scores]: j goes when some other specialist i loses little on j's checks design by design,
    mean_c max(S[j, j, c] - S[i, j, c], 0) <= merge_tol x scale. The absorber (the i of the smallest loss)
    takes j's designs and keeps its checkpoint. Smallest losses first; a specialist absorbed or absorbing this
    round is not merged again, and K stays >= K_min. Every specialist, the first K too, is judged only after
    challenge_rounds rounds of its own training, or at the round cap (capped: no more training)."""
    K, scale = len(S), score_scale(S)
    cands = []
    for j in range(K):
        others = [i for i in range(K) if i != j]
        if others:
            loss = np.array([np.maximum(S[j, j] - S[i, j], 0).mean() for i in others])
            cands.append((loss.min() / scale, j, others[int(np.argmin(loss))]))
    gone, absorbers, events = set(), set(), list(terr["events"])
    # a specialist (and its pair) is judged only after challenge_rounds rounds of its own training, or at the cap
    fresh = set() if capped else young(terr, config, r)
    eta = list(terr["eta"])
    for gap, j, i in sorted(cands, key=lambda c: (c[0], -c[1])):   # ties: the younger goes
        if gap > config.merge_tol or K - len(gone) <= config.K_min:
            break
        if j in gone or j in absorbers or i in gone or j in fresh or i in fresh:
            continue
        eta[i] = np.vstack([eta[i], eta[j]])
        gone.add(j)
        absorbers.add(i)
        events.append({"kind": "merge", "id": terr["ids"][j], "into": terr["ids"][i], "gap": float(gap),
                       "reason": f"specialist {terr['ids'][i]} serves its checks within {gap:.1%} of the scale"})
    # backoff: a territory that takes back a challenger it begot (one refuted split) waits twice as long
    strikes = dict(terr.get("strikes", {}))
    for e in events[len(terr["events"]):]:
        if terr["parent"].get(str(e["id"])) == e["into"]:
            strikes[str(e["into"])] = strikes.get(str(e["into"]), 0) + 1
    wait = dict(terr["wait"], **{str(terr["ids"][i]): r + 1 + config.split_cooldown * 2 ** strikes.get(
        str(terr["ids"][i]), 0) for i in absorbers})
    keep = [k for k in range(K) if k not in gone]
    return dict(terr, ids=[terr["ids"][k] for k in keep], eta=[eta[k] for k in keep],
                ckpt=[terr["ckpt"][k] for k in keep], wait=wait, events=events, strikes=strikes)


def two_means(x: np.ndarray, iters: int = 10) -> np.ndarray:
    """Labels 0/1 of a 2-means (Lloyd) split of x, started from the two points at the ends of its widest axis:
    deterministic, no draw."""
    a = int(np.argmax(x.var(axis=0)))
    c = lloyd(np.stack([x[np.argmin(x[:, a])], x[np.argmax(x[:, a])]]), x, iters)
    return np.argmin(((x[:, None, :] - c[None]) ** 2).sum(-1), axis=1)


def split(terr: dict, checks: np.ndarray, S: np.ndarray, config: GESConfig, r: int, d: int) -> dict:
    """Challenge each territory its specialist serves unevenly [ours; G-means' split test]: 2-means its checks;
    if the specialist's mean score on the two halves differs by more than split_gap x scale, the lower half
    becomes a challenger's territory, started from the parent's checkpoint; the parent keeps the upper half
    (its designs and checks, split by 2-means label). At most one split per territory and round, K <= K_max;
    a territory waits a round after a split, split_cooldown rounds after absorbing one, doubled for each
    challenger of its own it took back (exponential backoff: a refuted challenger is not reborn every round)."""
    scale, out = score_scale(S), dict(terr, ids=list(terr["ids"]), eta=list(terr["eta"]), ckpt=list(terr["ckpt"]),
                                      wait=dict(terr["wait"]), events=list(terr["events"]), born=dict(terr["born"]),
                                      parent=dict(terr["parent"]))
    for k in range(len(S)):
        pid = terr["ids"][k]
        if len(out["ids"]) >= config.K_max or out["wait"].get(str(pid), 0) > r:
            continue
        lab = two_means(checks[k])
        if min(np.sum(lab == 0), np.sum(lab == 1)) < 2:
            continue
        m = np.array([S[k, k][lab == g].mean() for g in (0, 1)])
        gap, lo = (m.max() - m.min()) / scale, int(np.argmin(m))
        if gap <= config.split_gap:
            continue
        held = np.vstack([np.asarray(terr["eta"][k]).reshape(-1, d), checks[k]])
        centre = [checks[k][lab == g].mean(axis=0) for g in (0, 1)]
        side = np.argmin(np.stack([((held - c) ** 2).sum(1) for c in centre]), axis=0)
        if min(np.sum(side == 0), np.sum(side == 1)) < 2:
            continue
        cid = out["next_id"]
        out["eta"][k] = held[side != lo]
        out["ids"].append(cid)
        out["eta"].append(held[side == lo])
        out["ckpt"].append(terr["ckpt"][k])
        out["wait"].update({str(pid): r + 2, str(cid): r + 2})
        out["born"][str(cid)] = r
        out["parent"][str(cid)] = pid
        out["next_id"] = cid + 1
        out["events"].append({"kind": "split", "id": pid, "child": cid, "gap": float(gap),
                              "reason": f"its checks' halves score {m.max():.3g} and {m.min():.3g}: "
                                        f"{gap:.1%} of the scale apart"})
    return out


# ---------------------------------------------------------------------------------------------------------
# 9. Command line: demo, sweep, bench, experiments/ges_demo.py's, in a child process (ges imports no tool built on it)
# ---------------------------------------------------------------------------------------------------------
def main(argv=None) -> int:
    """`python ges.py demo --out OUT [--K auto --sites B] | sweep | bench`: runs `python -m experiments.ges_demo`
    (the synthetic landscape and the figure, which import ges) with the same arguments; returns its exit code."""
    from runkit.args import delegate
    return delegate("experiments.ges_demo", argv)


if __name__ == "__main__":
    sys.exit(main())
