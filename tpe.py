"""Tree-structured Parzen Estimator (TPE) for the outer design search.

TPE (Bergstra et al., NeurIPS 2011) is the design optimiser the GES paper uses
("Design optimization uses TPE"). It is a cheap Bayesian optimiser: instead of
fitting a model of y(x) it fits two densities over the design box,

    l(x) = density of the good trials (the best gamma(n) so far),
    g(x) = density of the bad trials (all the others),

draws a few candidates from l(x) and proposes the one where l(x)/g(x) is the
largest, i.e. a design that looks like the good ones and unlike the bad ones.

Read this file top to bottom:
  1. TPEConfig          every setting, with its default and why
  2. small rules        gamma (good/bad split), recency weights, bandwidths
  3. truncated Gaussian log-density and sampler on [low, high]
  4. Parzen estimator   mixture of truncated Gaussians + one broad prior kernel
  5. TPE                ask/tell study: suggest() / observe(x, y), JSON file, resume
  6. optimize()         the loop run_all.py calls
  7. demo and bench: `python tpe.py demo | bench`

Usage:
    study = optimize(f, lows=[0.5, 0.0], highs=[1.0, 0.01], n_trials=50, seed=0,
                     path="runs/design_tpe.json", names=["gcr", "spcf"])
    study.best.x, study.best.y

Determinism: suggestion number i draws only from a numpy Generator seeded with
(seed, i) and depends only on the finished trials, so the same seed gives the
same trials, and a study resumed from its file continues exactly as an
uninterrupted one would.
"""
from __future__ import annotations

import json
import math
import os
import time
from dataclasses import asdict, dataclass
from typing import Callable

import numpy as np
from scipy.special import ndtr, ndtri

from runkit.files import write_json   # atomic: a crash never leaves half a study file
from runkit.settings import integer, need   # a bad setting: one line

FILE_FORMAT = "tpe-study-v1"


# ----------------------------------------------------------------------------
# 1. Settings
# ----------------------------------------------------------------------------
@dataclass
class TPEConfig:
    n_startup: int = 10             # first trials are uniform random: densities need data
    n_candidates: int = 24          # candidates drawn from l(x) per suggestion (TPE paper: 24)
    gamma_frac: float = 0.1         # good set = best ceil(gamma_frac * n) finished trials ...
    gamma_max: int = 25             # ... but at most this many (keeps l(x) focused late on)
    n_recent: int = 25              # the newest n_recent trials of a set get weight 1, older
                                    # ones ramp linearly down to 1/n (old data counts less)
    prior_weight: float = 1.0       # weight of the broad prior kernel (centre, width = range)
    min_bw_cap: float = 100.0       # min sigma = range / min(min_bw_cap, n + 2) (>= range/100)
    multivariate: bool = False      # False: product of 1-D mixtures; True: joint kernels
    direction: str = "minimize"     # "minimize" or "maximize" the objective

    def __post_init__(self):   # one line naming a bad setting and what is allowed (runkit.settings)
        for name, least in (("n_startup", 0), ("n_candidates", 1), ("gamma_max", 1), ("n_recent", 1)):
            integer(self, name, least)
        need(self, "gamma_frac", 0.0 < self.gamma_frac <= 1.0, "in (0, 1]")
        need(self, "prior_weight", math.isfinite(self.prior_weight) and self.prior_weight > 0, "a finite number > 0")
        need(self, "min_bw_cap", math.isfinite(self.min_bw_cap) and self.min_bw_cap >= 1, "a finite number >= 1")
        need(self, "multivariate", isinstance(self.multivariate, bool), "True or False")
        need(self, "direction", self.direction in ("minimize", "maximize"), "'minimize' or 'maximize'")


def _check_int(name: str, value, minimum: int):
    """An argument (seed, n_trials, parallel) checked as runkit.settings.integer checks a setting. Reject floats/bools
    early: a silently truncated count is a hard-to-see bug."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")


# ----------------------------------------------------------------------------
# 2. Small rules: how many trials are "good", how much each counts, how wide
# ----------------------------------------------------------------------------
def n_good(n: int, cfg: TPEConfig) -> int:
    """gamma(n) = min(ceil(0.1 n), 25): a small elite, so l(x) is sharp."""
    return min(math.ceil(cfg.gamma_frac * n), cfg.gamma_max)


def recency_weights(n: int, cfg: TPEConfig) -> np.ndarray:
    """Weights of n trials in chronological order (oldest first).

    The newest `n_recent` get weight 1; older ones ramp linearly from 1/n (the
    oldest) up towards 1, so early, crude samples fade as the search narrows.
    """
    if n <= cfg.n_recent:
        return np.ones(n)
    ramp = np.linspace(1.0 / n, 1.0, n - cfg.n_recent)
    return np.concatenate([ramp, np.ones(cfg.n_recent)])


def bandwidths(X: np.ndarray, lows: np.ndarray, highs: np.ndarray, cfg: TPEConfig) -> np.ndarray:
    """(n, D) kernel widths for the trials X (n, D): the neighbour-distance rule.

    Per dimension, a kernel is as wide as the larger gap to its neighbouring
    centres (the rule of the TPE paper / hyperopt; the extreme points use their
    one inner gap). Dense clusters of good trials thus get narrow kernels and
    are refined, isolated trials get wide ones and keep exploring. A fixed
    Scott-like width (0.2 range n^(-1/(d+4))) was tried and stayed no better
    than random search on Branin, because it cannot narrow inside a cluster.
    Widths are clipped to [range / min(100, n + 2), range]: the minimum (the
    "magic clip") stops kernels collapsing onto a point while trials are few.
    """
    n, D = X.shape
    ranges = highs - lows
    sigma = np.tile(ranges, (n, 1))  # a lone trial: as wide as the box
    if n >= 2:
        order = np.argsort(X, axis=0)
        gaps = np.diff(np.take_along_axis(X, order, axis=0), axis=0)   # (n-1, D)
        gaps = np.pad(gaps, ((1, 1), (0, 0)))                        # no neighbour: gap 0
        np.put_along_axis(sigma, order, np.maximum(gaps[:-1], gaps[1:]), axis=0)
    min_sigma = ranges / min(cfg.min_bw_cap, n + 2)
    return np.clip(sigma, min_sigma, ranges)


# ----------------------------------------------------------------------------
# 3. Truncated Gaussian on [low, high] (vectorised, broadcasting)
# ----------------------------------------------------------------------------
_LOG_SQRT_2PI = 0.5 * math.log(2 * math.pi)


def logsumexp(a: np.ndarray, axis: int) -> np.ndarray:
    """log(sum(exp(a))) without overflow (scipy's version is ~4x slower here)."""
    m = a.max(axis=axis, keepdims=True)
    return np.squeeze(m, axis) + np.log(np.exp(a - m).sum(axis=axis))


def trunc_log_pdf(x, mu, sigma, low, high):
    """log N(x; mu, sigma) renormalised to [low, high] (x assumed inside).

    All kernel centres lie inside the box, so the normaliser Phi(b) - Phi(a)
    is at least Phi(1) - Phi(0) = 0.34: the plain difference is accurate.
    """
    z = (x - mu) / sigma
    mass = ndtr((high - mu) / sigma) - ndtr((low - mu) / sigma)
    return -0.5 * z * z - np.log(sigma) - _LOG_SQRT_2PI - np.log(mass)


def trunc_sample(rng: np.random.Generator, mu, sigma, low, high):
    """Inverse-CDF sampling: u ~ U(Phi(a), Phi(b)), x = mu + sigma Phi^-1(u).

    Exact (no rejection loop), and one uniform draw per sample keeps the RNG
    stream easy to reason about. Clipping only removes float round-off.
    """
    a = ndtr((low - mu) / sigma)
    b = ndtr((high - mu) / sigma)
    u = rng.uniform(a, b)
    return np.clip(mu + sigma * ndtri(u), low, high)


# ----------------------------------------------------------------------------
# 4. Parzen estimator: weighted mixture of truncated Gaussians + a prior kernel
# ----------------------------------------------------------------------------
@dataclass
class Parzen:
    mus: np.ndarray         # (K, D) kernel centres: the trials, then the box centre
    sigmas: np.ndarray      # (K, D) kernel widths
    weights: np.ndarray     # (K,) mixture weights, sum to 1
    lows: np.ndarray        # (D,)
    highs: np.ndarray       # (D,)
    multivariate: bool      # joint kernels (True) or product of 1-D mixtures (False)

    def log_kernels(self, x: np.ndarray) -> np.ndarray:
        """(N, K, D) log-density of every point under every kernel, per dimension."""
        return trunc_log_pdf(x[:, None, :], self.mus, self.sigmas, self.lows, self.highs)

    def log_pdf(self, x: np.ndarray) -> np.ndarray:
        """(N,) log-density of points x (N, D).

        multivariate: log sum_k w_k prod_d k_d(x_d)
        univariate:   sum_d log sum_k w_k k_d(x_d)
        """
        log_k = self.log_kernels(np.atleast_2d(x))
        log_w = np.log(self.weights)
        if self.multivariate:
            return logsumexp(log_w[None, :] + log_k.sum(axis=2), axis=1)
        return logsumexp(log_w[None, :, None] + log_k, axis=1).sum(axis=1)

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """(n, D) samples. Multivariate: one kernel per sample for all dimensions;
        univariate: an independent kernel choice per dimension."""
        K, D = self.mus.shape
        shape = (n,) if self.multivariate else (n, D)
        k = rng.choice(K, size=shape, p=self.weights)
        if self.multivariate:
            mu, sigma = self.mus[k], self.sigmas[k]
        else:
            mu, sigma = self.mus[k, np.arange(D)], self.sigmas[k, np.arange(D)]
        return trunc_sample(rng, mu, sigma, self.lows, self.highs)


def build_parzen(X: np.ndarray, lows: np.ndarray, highs: np.ndarray, cfg: TPEConfig) -> Parzen:
    """Parzen estimator of trials X (n, D), given oldest first.

    One kernel per trial (recency-weighted) plus the prior kernel at the box
    centre with width = range, which keeps every region reachable.
    """
    n = X.shape[0]
    mus = np.vstack([X, (lows + highs) / 2])
    sigmas = np.vstack([bandwidths(X, lows, highs, cfg), highs - lows])
    weights = np.append(recency_weights(n, cfg), cfg.prior_weight)
    return Parzen(mus, sigmas, weights / weights.sum(), lows, highs, cfg.multivariate)


# ----------------------------------------------------------------------------
# 5. The study: ask (suggest) / tell (observe), saved to JSON, resumable
# ----------------------------------------------------------------------------
@dataclass
class Trial:
    index: int                   # 0, 1, 2, ... in the order trials were observed
    x: np.ndarray                # (D,) the design
    y: float | None              # objective value; None when the trial failed
    error: str | None = None     # why it failed (exception text / "non-finite value")
    seconds: float | None = None # wall time of the objective, if known

    @property
    def ok(self) -> bool:
        return self.y is not None

    def to_json(self) -> dict:
        return {"index": self.index, "x": [float(v) for v in self.x], "y": self.y,
                "error": self.error, "seconds": self.seconds}

    @staticmethod
    def from_json(d: dict) -> "Trial":
        return Trial(d["index"], np.array(d["x"], dtype=float), d["y"], d["error"], d["seconds"])


def _check_bounds(lows, highs) -> tuple[np.ndarray, np.ndarray]:
    lows = np.asarray(lows, dtype=float)
    highs = np.asarray(highs, dtype=float)
    if lows.ndim != 1 or lows.size == 0 or lows.shape != highs.shape:
        raise ValueError(f"lows and highs must be non-empty 1-D arrays of equal length, "
                         f"got shapes {lows.shape} and {highs.shape}")
    if not (np.all(np.isfinite(lows)) and np.all(np.isfinite(highs))):
        raise ValueError(f"lows and highs must be finite, got lows={lows}, highs={highs}")
    if np.any(lows >= highs):
        raise ValueError(f"every low must be < its high, got lows={lows}, highs={highs}")
    return lows, highs


class TPE:
    """Ask/tell TPE study over the box [lows, highs].

    suggest() is a pure function of (seed, finished trials): calling it twice
    without observe() in between returns the same point.
    """

    def __init__(self, lows, highs, config: TPEConfig | None = None, seed: int = 0,
                 names: list[str] | None = None, path: str | None = None):
        self.lows, self.highs = _check_bounds(lows, highs)
        self.dim = self.lows.size
        self.config = config if config is not None else TPEConfig()
        if not isinstance(self.config, TPEConfig):
            raise ValueError(f"config must be a TPEConfig, got {type(self.config).__name__}")
        _check_int("seed", seed, 0)
        self.seed = int(seed)
        self.names = [f"x{i}" for i in range(self.dim)] if names is None else [str(s) for s in names]
        if len(self.names) != self.dim:
            raise ValueError(f"names must have {self.dim} entries (one per dimension), got {len(self.names)}")
        self.path = path
        self.trials: list[Trial] = []
        if path is not None and os.path.exists(path):
            self._load(path)

    # --- ask -----------------------------------------------------------------
    def suggest(self) -> np.ndarray:
        """Next design to evaluate: random during startup, then the TPE proposal."""
        ok = [t for t in self.trials if t.ok]
        if len(ok) < self.config.n_startup:
            return self._startup_point(len(self.trials))
        rng = np.random.default_rng([self.seed, len(self.trials)])
        good, bad = self.split(ok)
        l = build_parzen(good, self.lows, self.highs, self.config)
        g = build_parzen(bad, self.lows, self.highs, self.config)
        candidates = l.sample(rng, self.config.n_candidates)
        score = l.log_pdf(candidates) - g.log_pdf(candidates)
        return candidates[np.argmax(score)]

    def startup_batch(self, n: int) -> list[np.ndarray]:
        """Up to n next designs that are random startup draws whatever the pending trials return. Draw i
        depends only on (seed, i) and a pending trial can only delay the end of startup, so evaluating these in
        parallel gives exactly the trials of the sequential loop. [ours] For run_all's cost stage: per-design
        BO's trials run one per core, as every other training job does (a fair cost layout)."""
        n_ok = sum(t.ok for t in self.trials)
        m = max(0, min(n, self.config.n_startup - n_ok))
        return [self._startup_point(len(self.trials) + j) for j in range(m)]

    def _startup_point(self, i: int) -> np.ndarray:
        """Trial i's random startup design: uniform over the box, from (seed, i) alone."""
        return np.random.default_rng([self.seed, i]).uniform(self.lows, self.highs)

    def split(self, ok: list[Trial]) -> tuple[np.ndarray, np.ndarray]:
        """Good/bad designs (each oldest first); ties go to the older trial."""
        y = np.array([t.y for t in ok])
        loss = y if self.config.direction == "minimize" else -y
        order = np.argsort(loss, kind="stable")
        n = n_good(len(ok), self.config)
        X = np.array([t.x for t in ok]).reshape(len(ok), self.dim)
        return X[np.sort(order[:n])], X[np.sort(order[n:])]

    # --- tell ----------------------------------------------------------------
    def observe(self, x, y, error: str | None = None, seconds: float | None = None) -> Trial:
        """Record a finished trial. y None / NaN / inf (or an error) = failed trial:
        kept in the record, left out of the densities."""
        x = self._check_point(x)
        if y is not None:
            try:
                y = float(y)
            except (TypeError, ValueError):
                raise ValueError(f"y must be a real number or None, got {y!r}") from None
            if not math.isfinite(y):
                error = error or f"non-finite objective value {y}"
        if error is not None:
            y = None
        trial = Trial(len(self.trials), x, y, error, seconds)
        self.trials.append(trial)
        if self.path is not None:
            self._save(self.path)
        return trial

    def _check_point(self, x) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        if x.shape != (self.dim,):
            raise ValueError(f"x must have shape ({self.dim},), got {x.shape}")
        if not np.all(np.isfinite(x)) or np.any(x < self.lows) or np.any(x > self.highs):
            raise ValueError(f"x must be finite and inside [lows, highs] = [{self.lows}, {self.highs}], got {x}")
        return x.copy()

    # --- results -------------------------------------------------------------
    @property
    def best(self) -> Trial | None:
        """Best successful trial (per direction), None if there is none yet."""
        ok = [t for t in self.trials if t.ok]
        if not ok:
            return None
        sign = 1.0 if self.config.direction == "minimize" else -1.0
        return min(ok, key=lambda t: sign * t.y)  # min() keeps the first of ties

    # --- file ------------------------------------------------------------------
    def _header(self) -> dict:
        return {"format": FILE_FORMAT, "seed": self.seed, "lows": self.lows.tolist(),
                "highs": self.highs.tolist(), "names": self.names, "config": asdict(self.config)}

    def _save(self, path: str):
        """Atomic write (runkit.files.write_json): a crash never leaves half a file."""
        write_json(path, self._header() | {"trials": [t.to_json() for t in self.trials]})

    def _load(self, path: str):
        """Resume: the file must describe the same study, else its trials would
        not be the ones this study would have made."""
        data = read_study(path)
        for key, value in self._header().items():
            if data.get(key) != value:
                raise ValueError(f"path {path!r} holds a study with a different {key}: "
                                 f"{data.get(key)!r} in the file vs {value!r} here")
        self.trials = [Trial.from_json(d) for d in data["trials"]]


def read_study(path: str) -> dict:
    """A study file's content, checked: ValueError naming the file and what to do if it is truncated,
    garbage (not UTF-8 JSON) or of another format, instead of a JSON / Unicode traceback."""
    try:
        with open(path) as fh:
            data = json.load(fh)
        if data.get("format") != FILE_FORMAT:
            raise ValueError(f"format {data.get('format')!r}")
        [Trial.from_json(d) for d in data["trials"]]
    except (ValueError, KeyError, TypeError, AttributeError, IndexError) as exc:
        why = f"{type(exc).__name__}: {str(exc).splitlines()[0][:80]}" if str(exc) else type(exc).__name__
        raise ValueError(f"path {path!r} is not a {FILE_FORMAT} study file ({why}); delete it to start "
                         f"that study over") from None
    return data


# ----------------------------------------------------------------------------
# 6. The optimisation loop
# ----------------------------------------------------------------------------
def optimize(f: Callable[[np.ndarray], float], lows, highs, n_trials: int, seed: int = 0,
             config: TPEConfig | None = None, path: str | None = None,
             names: list[str] | None = None,
             callback: Callable[[TPE, Trial], None] | None = None,
             verbose: bool = True, executor=None, parallel: int = 1) -> TPE:
    """Run f until the study holds n_trials trials and return the study.

    With an `executor` and parallel > 1, the startup trials run `parallel` at a time on it (startup_batch:
    the same trials as the sequential loop); the TPE proposals after them stay sequential.

    n_trials counts trials already in the file at `path`, so re-running the
    same call after a crash finishes the job instead of starting over. An
    objective that raises (Exception) or returns NaN/inf is a failed trial;
    KeyboardInterrupt and friends still stop the run (the file is up to date).
    """
    _check_int("n_trials", n_trials, 1)
    _check_int("parallel", parallel, 1)
    if parallel > 1 and executor is None:
        raise ValueError(f"parallel={parallel} needs an executor (a concurrent.futures.Executor)")
    study = TPE(lows, highs, config, seed, names=names, path=path)
    while len(study.trials) < n_trials:
        batch = study.startup_batch(min(parallel, n_trials - len(study.trials))) if parallel > 1 else []
        if len(batch) > 1:
            futures = [executor.submit(timed_call, f, x) for x in batch]
            outcomes = [fut.result() for fut in futures]
        else:
            batch = [study.suggest()]
            outcomes = [timed_call(f, batch[0])]
        for x, (y, error, seconds) in zip(batch, outcomes):   # observed in draw order, as the loop would
            trial = study.observe(x, y, error=error, seconds=seconds)
            if verbose:
                print(progress_line(study, trial, n_trials), flush=True)
            if callback is not None:
                callback(study, trial)
    return study


def timed_call(f: Callable[[np.ndarray], float], x: np.ndarray) -> tuple:
    """(y, error, seconds) of one trial, timed where it runs. An objective that raises (Exception) is a
    failed trial: a broken design must not kill a long search."""
    start = time.perf_counter()
    try:
        y, error = float(f(x)), None
    except Exception as exc:
        y, error = None, f"{type(exc).__name__}: {exc}"
    return y, error, time.perf_counter() - start


def progress_line(study: TPE, trial: Trial, n_trials: int) -> str:
    xs = " ".join(f"{n}={v:.4g}" for n, v in zip(study.names, trial.x))
    y = f"{trial.y:.5g}" if trial.ok else f"FAILED ({trial.error})"
    best = study.best
    best_txt = f"{best.y:.5g} (#{best.index})" if best is not None else "-"
    return f"[tpe] trial {trial.index + 1}/{n_trials}  {xs}  y={y}  best={best_txt}  {trial.seconds or 0:.2f}s"


# ----------------------------------------------------------------------------
# 7. Demo (python tpe.py demo), speed check (python tpe.py bench) and the command line
# ----------------------------------------------------------------------------
BRANIN_LOWS, BRANIN_HIGHS, BRANIN_MIN = [-5.0, 0.0], [10.0, 15.0], 0.397887


def branin(x: np.ndarray) -> float:
    """Standard 2-D test function, global minimum 0.397887 at three points."""
    a, b, c, r, s, t = 1.0, 5.1 / (4 * math.pi ** 2), 5 / math.pi, 6.0, 10.0, 1 / (8 * math.pi)
    return a * (x[1] - b * x[0] ** 2 + c * x[0] - r) ** 2 + s * (1 - t) * math.cos(x[0]) + s


def demo(n_trials: int = 60, seeds=range(5)):
    """Best Branin value found by TPE vs random search (same budget, same seeds)."""
    random_cfg = TPEConfig(n_startup=n_trials)  # never leaves the random startup phase
    print(f"Branin, {n_trials} trials, optimum {BRANIN_MIN}")
    for seed in seeds:
        tpe_best = optimize(branin, BRANIN_LOWS, BRANIN_HIGHS, n_trials, seed, verbose=False).best
        rnd_best = optimize(branin, BRANIN_LOWS, BRANIN_HIGHS, n_trials, seed, random_cfg, verbose=False).best
        print(f"  seed {seed}: TPE {tpe_best.y:.4f} at {np.round(tpe_best.x, 3)}   random {rnd_best.y:.4f}")


def _median_seconds(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def bench(dim: int = 4, sizes=(100, 500), repeats: int = 30):
    """Time one suggest() with n finished trials next to references measured now."""
    lows, highs = np.zeros(dim), np.ones(dim)
    cfg = TPEConfig()
    print(f"time per suggestion, dim={dim}, median of {repeats} (ms)")
    print(f"{'trials':>7} {'TPE suggest':>12} {'random suggest':>15} {'24xn kernel matrix':>19}")
    for n in sizes:
        study = TPE(lows, highs, cfg, seed=0)
        rng = np.random.default_rng(0)
        for _ in range(n):
            x = rng.uniform(lows, highs)
            study.observe(x, float(np.sum((x - 0.3) ** 2)))
        random_study = TPE(lows, highs, TPEConfig(n_startup=10 ** 9), seed=0)
        random_study.trials = list(study.trials)
        l = build_parzen(rng.uniform(lows, highs, (n, dim)), lows, highs, cfg)
        cands = rng.uniform(lows, highs, (cfg.n_candidates, dim))
        t_tpe = _median_seconds(study.suggest, repeats)
        t_rnd = _median_seconds(random_study.suggest, repeats)
        t_ker = _median_seconds(lambda: l.log_kernels(cands), repeats)
        print(f"{n:>7} {1e3 * t_tpe:>12.3f} {1e3 * t_rnd:>15.3f} {1e3 * t_ker:>19.3f}")


COMMANDS = """tpe.py -- a Tree-structured Parzen Estimator; its command line tries it on Branin and times it.

    python tpe.py demo     # best Branin value of TPE vs random search, 60 trials, seeds 0-4
    python tpe.py bench    # time one suggestion at 100 and 500 trials
"""


def main(argv=None) -> int:
    """`python tpe.py demo | bench` (runkit/args.py: the command lines' vocabulary)."""
    from runkit import args
    ap = args.program("python tpe.py", COMMANDS)
    sub = ap.add_subparsers(dest="cmd", required=True)
    args.command(sub, "demo", "best Branin value found by TPE vs random search (same budget, same seeds)", COMMANDS)
    args.command(sub, "bench", "time one suggestion at 100 and 500 trials", COMMANDS)
    a = args.parse(ap, argv, {"--bench": ("bench", False)})
    bench() if a.cmd == "bench" else demo()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
