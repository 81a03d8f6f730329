# ============================================================================
# tpe.py: Tree-structured Parzen Estimator for the outer design search
# (self-contained section; runs in a few seconds)
# ============================================================================
import functools
import json
import math

import numpy as np
import pytest
from scipy import stats

from tpe import (TPE, Parzen, TPEConfig, bandwidths, build_parzen, n_good, optimize,
                 recency_weights)

BRANIN_BOX = ([-5.0, 0.0], [10.0, 15.0])
BRANIN_OPT = 0.397887
SPHERE_BOX = ([-5.0] * 5, [5.0] * 5)
SPHERE_CENTRE = np.array([1.5, -2.0, 0.5, 3.0, -1.0])  # off the box centre, where the
                                                       # prior kernel sits, to be fair
BENCH_SEEDS = range(7)
BENCH_TRIALS = 100


def branin_ref(x):
    """Branin written out independently of tpe.branin."""
    x1, x2 = x
    return ((x2 - 5.1 / (4 * np.pi ** 2) * x1 ** 2 + 5 / np.pi * x1 - 6) ** 2
            + 10 * (1 - 1 / (8 * np.pi)) * np.cos(x1) + 10)


def sphere(x):
    return float(np.sum((x - SPHERE_CENTRE) ** 2))


def quadratic(x):
    return float(np.sum((np.asarray(x) - 0.3) ** 2))


PROBLEMS = {"branin": (branin_ref, BRANIN_BOX, BRANIN_OPT), "sphere5": (sphere, SPHERE_BOX, 0.0)}
RANDOM = TPEConfig(n_startup=BENCH_TRIALS)  # never leaves the uniform random startup phase


@functools.lru_cache(maxsize=None)
def median_excess(problem, multivariate, random):
    """Median over seeds of (best value after BENCH_TRIALS) - (known optimum)."""
    f, (lows, highs), opt = PROBLEMS[problem]
    cfg = RANDOM if random else TPEConfig(multivariate=multivariate)
    bests = [optimize(f, lows, highs, BENCH_TRIALS, s, cfg, verbose=False).best.y for s in BENCH_SEEDS]
    return float(np.median(bests)) - opt


# Measured (7 seeds, 100 trials), median excess over the optimum:
#   branin : random 0.174, TPE univariate 0.028, multivariate 0.033  (ratio <= 0.19)
#   sphere5: random 5.90,  TPE univariate 0.71,  multivariate 0.22   (ratio <= 0.12)
# We demand ratio < 0.4 (Branin) and < 0.3 (sphere): a >2x margin over the measured
# ratios for seed noise. Checked by mutation: proposing the argmin of l/g instead of
# the argmax fails all four cases; dropping g (score = l only, still a sampler around
# the good trials) fails only Branin multivariate.
@pytest.mark.parametrize("multivariate", [False, True])
@pytest.mark.parametrize("problem,max_ratio", [("branin", 0.4), ("sphere5", 0.3)])
def test_tpe_beats_random_search(problem, max_ratio, multivariate):
    tpe_excess = median_excess(problem, multivariate, random=False)
    random_excess = median_excess(problem, multivariate, random=True)
    print(f"{problem} multivariate={multivariate}: median excess TPE {tpe_excess:.4f} "
          f"vs random {random_excess:.4f}")
    assert tpe_excess < max_ratio * random_excess


# --- the Parzen estimator against an explicit scipy.stats.truncnorm mixture ---
def random_parzen(rng, n, lows, highs, multivariate):
    cfg = TPEConfig(n_recent=3, prior_weight=0.7, multivariate=multivariate)  # uneven weights
    X = rng.uniform(lows, highs, (n, len(lows)))
    return build_parzen(X, np.asarray(lows), np.asarray(highs), cfg)


def truncnorm_pdfs(p: Parzen, x):
    """(N, K, D) kernel densities from scipy.stats.truncnorm, one kernel at a time."""
    N, (K, D) = len(x), p.mus.shape
    out = np.empty((N, K, D))
    for k in range(K):
        for d in range(D):
            mu, s = p.mus[k, d], p.sigmas[k, d]
            a, b = (p.lows[d] - mu) / s, (p.highs[d] - mu) / s
            out[:, k, d] = stats.truncnorm.pdf(x[:, d], a, b, loc=mu, scale=s)
    return out


@pytest.mark.parametrize("multivariate", [False, True])
def test_parzen_log_pdf_equals_truncnorm_mixture(multivariate):
    rng = np.random.default_rng(1)
    lows, highs = [-1.0, 0.0, 10.0], [2.0, 0.01, 30.0]
    p = random_parzen(rng, 9, lows, highs, multivariate)
    assert len(p.weights) == 10 and np.isclose(p.weights.sum(), 1.0)
    assert len(set(np.round(p.weights, 12))) > 2  # the check covers unequal weights
    x = np.vstack([rng.uniform(lows, highs, (50, 3)), lows, highs])  # incl. the bounds
    pdf = truncnorm_pdfs(p, x)
    if multivariate:   # sum_k w_k prod_d k_d(x_d)
        ref = np.log((p.weights[None, :] * pdf.prod(axis=2)).sum(axis=1))
    else:              # prod_d sum_k w_k k_d(x_d)
        ref = np.log((p.weights[None, :, None] * pdf).sum(axis=1)).sum(axis=1)
    np.testing.assert_allclose(p.log_pdf(x), ref, rtol=1e-10, atol=1e-10)


def test_parzen_prior_kernel_is_centre_with_range_width():
    p = random_parzen(np.random.default_rng(2), 4, [0.0, -3.0], [1.0, 5.0], False)
    np.testing.assert_array_equal(p.mus[-1], [0.5, 1.0])
    np.testing.assert_array_equal(p.sigmas[-1], [1.0, 8.0])


def test_parzen_samples_follow_the_mixture():
    """1-D samples pass a KS test against the truncnorm mixture's CDF."""
    rng = np.random.default_rng(3)
    p = random_parzen(rng, 6, [2.0], [5.0], False)
    samples = p.sample(np.random.default_rng(4), 20000)[:, 0]
    assert samples.min() >= 2.0 and samples.max() <= 5.0

    def cdf(x):
        return sum(w * stats.truncnorm.cdf(x, (2.0 - m) / s, (5.0 - m) / s, loc=m, scale=s)
                   for w, m, s in zip(p.weights, p.mus[:, 0], p.sigmas[:, 0]))

    assert stats.kstest(samples, cdf).pvalue > 1e-3


def test_multivariate_samples_keep_dimensions_together():
    """Two narrow kernels at (0.1, 0.1) and (0.9, 0.9): joint sampling stays near the
    diagonal; univariate sampling mixes dimensions (~half the mass off it)."""
    def make(multivariate):
        mus = np.array([[0.1, 0.1], [0.9, 0.9]])
        return Parzen(mus, np.full((2, 2), 0.02), np.array([0.5, 0.5]),
                      np.zeros(2), np.ones(2), multivariate)
    off_diagonal = {}
    for mv in (False, True):
        s = make(mv).sample(np.random.default_rng(5), 4000)
        off_diagonal[mv] = np.mean((s[:, 0] < 0.5) != (s[:, 1] < 0.5))
    assert off_diagonal[True] == 0.0
    assert 0.4 < off_diagonal[False] < 0.6


# --- the small rules ---
def test_gamma_rule():
    cfg = TPEConfig()
    assert [n_good(n, cfg) for n in (1, 10, 11, 100, 101, 250, 1000)] == [1, 1, 2, 10, 11, 25, 25]


def test_recency_weights():
    cfg = TPEConfig()
    np.testing.assert_array_equal(recency_weights(25, cfg), np.ones(25))
    w = recency_weights(30, cfg)
    np.testing.assert_allclose(w[:5], np.linspace(1 / 30, 1.0, 5))
    np.testing.assert_array_equal(w[5:], np.ones(25))


def test_neighbour_bandwidths():
    cfg = TPEConfig()
    lows, highs = np.array([0.0, 0.0]), np.array([1.0, 10.0])
    X = np.array([[0.5, 0.0], [0.0, 2.0], [1.0, 10.0], [0.1, 6.0]])
    # dim 0 sorted 0, .1, .5, 1 -> widest neighbour gap .1, .4, .5, .5; min width 1/6
    # dim 1 sorted 0, 2, 6, 10  -> 2, 4, 4, 4; min width 10/6 (no effect)
    expected = np.array([[0.5, 2.0], [1 / 6, 4.0], [0.5, 4.0], [0.4, 4.0]])
    np.testing.assert_allclose(bandwidths(X, lows, highs, cfg), expected)
    np.testing.assert_array_equal(bandwidths(X[:1], lows, highs, cfg), [[1.0, 10.0]])
    many = np.random.default_rng(0).uniform(lows, highs, (500, 2))
    assert np.all(bandwidths(many, lows, highs, cfg) >= (highs - lows) / 100)


# --- reproducibility and resuming ---
def flaky(x):
    """NaN in one corner, raises in another: failed trials must resume too."""
    if x[0] < 0.05:
        return float("nan")
    if x[1] > 0.95:
        raise RuntimeError("simulator diverged")
    return quadratic(x)


def records(study):
    return [(t.index, t.x.tolist(), t.y, t.error) for t in study.trials]


@pytest.mark.parametrize("multivariate", [False, True])
def test_same_seed_same_trials(multivariate):
    cfg = TPEConfig(multivariate=multivariate)
    run = lambda seed: optimize(flaky, [0, 0, 0], [1, 1, 1], 30, seed, cfg, verbose=False)
    assert records(run(3)) == records(run(3))
    assert records(run(3)) != records(run(4))


class Interrupt(BaseException):
    """Stands in for a crash / Ctrl-C: not an Exception, so it is not a failed trial."""


@pytest.mark.parametrize("stop_after", [4, 17])  # inside and after the random startup
def test_resumed_optimize_equals_uninterrupted(tmp_path, stop_after):
    box = ([0, 0], [1, 1])
    full = optimize(flaky, *box, 40, seed=5, path=str(tmp_path / "full.json"), verbose=False)
    calls = []

    def crashing(x):
        calls.append(1)
        if len(calls) > stop_after:
            raise Interrupt
        return flaky(x)

    path = str(tmp_path / "resumed.json")
    with pytest.raises(Interrupt):
        optimize(crashing, *box, 40, seed=5, path=path, verbose=False)
    assert len(json.load(open(path))["trials"]) == stop_after
    resumed = optimize(flaky, *box, 40, seed=5, path=path, verbose=False)
    assert records(resumed) == records(full)
    assert any(not t.ok for t in full.trials)  # the resume covered failed trials
    assert not (tmp_path / "resumed.json.tmp").exists()


def test_resumed_ask_tell_equals_uninterrupted(tmp_path):
    def drive(study, n):
        for _ in range(n):
            x = study.suggest()
            study.observe(x, quadratic(x))

    cfg = TPEConfig(multivariate=True, direction="minimize")
    full = TPE([0, 0, 0], [1, 1, 1], cfg, seed=9)
    drive(full, 25)
    path = str(tmp_path / "study.json")
    drive(TPE([0, 0, 0], [1, 1, 1], cfg, seed=9, path=path), 13)
    resumed = TPE([0, 0, 0], [1, 1, 1], cfg, seed=9, path=path)
    assert len(resumed.trials) == 13
    drive(resumed, 12)
    assert records(resumed) == records(full)


def test_resume_refuses_a_different_study(tmp_path):
    path = str(tmp_path / "study.json")
    optimize(quadratic, [0, 0], [1, 1], 3, seed=1, path=path, verbose=False)
    with pytest.raises(ValueError, match="seed"):
        TPE([0, 0], [1, 1], seed=2, path=path)
    with pytest.raises(ValueError, match="highs"):
        TPE([0, 0], [1, 2], seed=1, path=path)
    with pytest.raises(ValueError, match="config"):
        TPE([0, 0], [1, 1], TPEConfig(multivariate=True), seed=1, path=path)
    (tmp_path / "junk.json").write_text("{not json")
    with pytest.raises(ValueError, match="path"):
        TPE([0, 0], [1, 1], path=str(tmp_path / "junk.json"))


# --- bad input and failing objectives ---
@pytest.mark.parametrize("lows,highs,match", [
    ([0, 1], [1, 1], "low"), ([2.0], [1.0], "low"), ([0, np.nan], [1, 1], "finite"),
    ([0, 0], [1, np.inf], "finite"), ([0, 0], [1, 1, 1], "equal length"), ([], [], "non-empty")])
def test_bad_bounds_raise(lows, highs, match):
    with pytest.raises(ValueError, match=match):
        TPE(lows, highs)
    with pytest.raises(ValueError, match=match):
        optimize(quadratic, lows, highs, 5, verbose=False)


@pytest.mark.parametrize("n_trials", [0, -3, 2.5, True])
def test_bad_n_trials_raises(n_trials):
    with pytest.raises(ValueError, match="n_trials"):
        optimize(quadratic, [0], [1], n_trials, verbose=False)


@pytest.mark.parametrize("x", [[0.5], [0.5, 0.5, 0.5], [[0.5, 0.5]], [np.nan, 0.5], [0.5, 1.5]])
def test_bad_point_raises(x):
    with pytest.raises(ValueError, match="x must"):
        TPE([0, 0], [1, 1]).observe(x, 1.0)


@pytest.mark.parametrize("kwargs,match", [
    (dict(direction="max"), "direction"), (dict(gamma_frac=0.0), "gamma_frac"),
    (dict(n_candidates=0), "n_candidates"), (dict(n_startup=2.0), "n_startup"),
    (dict(prior_weight=-1.0), "prior_weight"), (dict(min_bw_cap=0.5), "min_bw_cap")])
def test_bad_config_raises(kwargs, match):
    with pytest.raises(ValueError, match=match):
        TPEConfig(**kwargs)


def test_bad_seed_names_and_y_raise():
    with pytest.raises(ValueError, match="seed"):
        TPE([0], [1], seed=-1)
    with pytest.raises(ValueError, match="names"):
        TPE([0, 0], [1, 1], names=["a"])
    with pytest.raises(ValueError, match="y must"):
        TPE([0], [1]).observe([0.5], "good")


def test_failing_objective_becomes_failed_trial(tmp_path):
    path = str(tmp_path / "study.json")
    study = optimize(flaky, [0, 0], [1, 1], 40, seed=0, path=path, verbose=False)
    failed = [t for t in study.trials if not t.ok]
    assert len(study.trials) == 40 and failed and len(failed) < 40
    assert {t.error.split(":")[0] for t in failed} <= {"RuntimeError", "non-finite objective value nan"}
    assert study.best.ok and study.best.y == min(t.y for t in study.trials if t.ok)
    saved = json.load(open(path))["trials"]  # failed trials are kept in the file
    assert [d["y"] is None for d in saved] == [not t.ok for t in study.trials]

    always_fails = optimize(lambda x: 1 / 0, [0], [1], 5, verbose=False)
    assert len(always_fails.trials) == 5 and always_fails.best is None
    # a failed trial must not freeze the search on the same point
    assert len({tuple(t.x) for t in always_fails.trials}) == 5


def test_failed_trials_are_left_out_of_the_densities():
    """Histories that differ only in where failed trials were give the same suggestions.
    (Failed points sit at the optimum in one history: were they counted, g(x) would
    push the proposal away from there.)"""
    for seed in range(8):
        xs = np.random.default_rng(seed).uniform(0, 1, (30, 2))
        studies = [TPE([0, 0], [1, 1], seed=seed), TPE([0, 0], [1, 1], seed=seed)]
        for i, x in enumerate(xs):
            if i % 4 == 3:
                studies[0].observe([0.3, 0.3], None, error="crash")
                studies[1].observe([0.99, 0.01], float("inf"))
            else:
                for s in studies:
                    s.observe(x, quadratic(x))
        assert studies[0].best.y == studies[1].best.y
        np.testing.assert_array_equal(studies[0].suggest(), studies[1].suggest())


# --- both directions, both modes ---
@pytest.mark.parametrize("multivariate", [False, True])
def test_maximize_mirrors_minimize(multivariate):
    """Maximising -f must make exactly the trials minimising f makes."""
    cfg = TPEConfig(multivariate=multivariate)
    mini = optimize(branin_ref, *BRANIN_BOX, 40, 0, cfg, verbose=False)
    maxi = optimize(lambda x: -branin_ref(x), *BRANIN_BOX, 40, 0,
                    TPEConfig(multivariate=multivariate, direction="maximize"), verbose=False)
    np.testing.assert_array_equal([t.x for t in maxi.trials], [t.x for t in mini.trials])
    assert maxi.best.y == -mini.best.y == max(t.y for t in maxi.trials)
    # and the search works: best of the 10 random startup trials is 9.46 for seed 0
    assert mini.best.y < 0.2 * min(t.y for t in mini.trials[:10])


@pytest.mark.parametrize("multivariate", [False, True])
def test_suggestions_stay_in_bounds(multivariate):
    lows, highs = [0.5, 0.0, -2.0, 100.0], [1.0, 0.01, 2.0, 101.0]
    study = optimize(lambda x: float(np.sum(x)), lows, highs, 40, 0,
                     TPEConfig(multivariate=multivariate), verbose=False)
    X = np.array([t.x for t in study.trials])
    assert X.shape == (40, 4) and np.all(X >= lows) and np.all(X <= highs)


def test_progress_lines_and_callback(capsys):
    seen = []
    optimize(flaky, [0, 0], [1, 1], 5, names=["gcr", "spcf"], verbose=True,
             callback=lambda study, trial: seen.append(trial.index))
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 5 and lines[0].startswith("[tpe] trial 1/5") and "gcr=" in lines[0]
    assert seen == [0, 1, 2, 3, 4]
    optimize(flaky, [0, 0], [1, 1], 5, verbose=False)
    assert capsys.readouterr().out == ""
