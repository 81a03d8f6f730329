"""The statistics of a report, beyond the paper, which gives none: bootstrap over test designs, paired
comparisons, and the verdict on a claim 'a > b' [ours]."""
from __future__ import annotations

import numpy as np


def wins(a: np.ndarray, b: np.ndarray) -> dict:
    """Head-to-head over the same test designs: % where a > b, % ties (scores are curriculum levels)."""
    return {"win_pct": float(100 * np.mean(a > b)), "tie_pct": float(100 * np.mean(a == b))}


N_BOOT = 10_000          # [ours] bootstrap resamples; the CI's Monte Carlo error is ~0.01 of its width
CI_LEVEL = 0.95


def bootstrap_ci(x, seed: int = 0, level: float = CI_LEVEL) -> tuple:
    """Percentile bootstrap CI of the mean over test designs (each design is one draw of the design space).
    scipy.stats.bootstrap(method="percentile") with the same Generator draws the same resamples but interpolates
    its percentiles differently in the last bit (3 of 200 random samples); ours is kept so committed results
    reproduce bit for bit."""
    x = np.asarray(x, dtype=float)
    idx = np.random.default_rng(seed).integers(0, len(x), (N_BOOT, len(x)))
    means = x[idx].mean(axis=1)
    return float(np.quantile(means, (1 - level) / 2)), float(np.quantile(means, (1 + level) / 2))


def paired_comparison(a, b, seed: int = 0) -> dict:
    """a vs b on the same test designs: mean difference with its paired-bootstrap CI, the Wilcoxon signed-rank
    p-value (two-sided; 1.0 when every pair ties), and the win rate of a (ties apart) with its bootstrap CI."""
    from scipy.stats import wilcoxon
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    d = a - b
    idx = np.random.default_rng(seed).integers(0, len(d), (N_BOOT, len(d)))
    q = ((1 - CI_LEVEL) / 2, (1 + CI_LEVEL) / 2)
    diff_lo, diff_hi = np.quantile(d[idx].mean(axis=1), q)
    win_lo, win_hi = np.quantile(100 * (d[idx] > 0).mean(axis=1), q)
    p = float(wilcoxon(a, b).pvalue) if np.any(d != 0) else 1.0
    return {"diff": float(d.mean()), "diff_lo": float(diff_lo), "diff_hi": float(diff_hi), "p": p,
            "win_lo": float(win_lo), "win_hi": float(win_hi), **wins(a, b)}


def verdict(cmp: dict, alpha: float = 0.05) -> str:
    """A claim 'a > b' from a paired comparison: supported (a higher, p < alpha), not supported (a lower,
    p < alpha) or not resolved."""
    if cmp["p"] < alpha:
        return "supported" if cmp["diff"] > 0 else "not supported"
    return "not resolved"
