"""experiments/ges_demo.py -- GES (ges.py) on a synthetic landscape, a cheap stand-in for BALLU+PPO (the tests,
the demo, the adaptive-K study experiments/ges_adaptive.py); the benchmark; ges.py's command line.

    python ges.py demo --out OUT [--dim 3] [--seed 0] [--workers 1]   # or: python -m experiments.ges_demo demo ...
    python ges.py demo --out OUT --K auto --sites 3   # adaptive K (ges.py section 8) on 3 planted sites; or --K 3
    python ges.py sweep                               # rounds to 95 % coverage per (n_init, F) on the demo landscape
    python ges.py bench                               # time one coverage estimate and one routing

`demo` runs GES to coverage and writes OUT/territories.png (report.figures.plot_territories, the planted regions
shaded in 2-D). [ours] throughout: the paper has no synthetic landscape.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np

from experiments import args
from ges import (Box, GESConfig, GESResult, SerialExecutor, coverage, rng_for, route_unit, routed_evaluator,
                 run_ges)
from report.figures import plot_territories
from runkit.files import write_json

# ---------------------------------------------------------------------------------------------------------
# 1. Synthetic landscape: a cheap stand-in for BALLU+PPO (tests, the demo)
# ---------------------------------------------------------------------------------------------------------
@dataclass(eq=False)
class PlantedLandscape:
    """Planted sites b in the unit cube; behaviour b is good near site b: quality q_b(x) =
    exp(-|x - site_b|^2 / (2 width^2)), so the best behaviour's regions are the sites' Voronoi cells.
    A specialist is a logit vector p over behaviours; its score on x is sum_b softmax(p)_b q_b(x). train()
    really improves it: gradient ascent on the mean score over designs drawn from its territory, i.e. toward
    the behaviour best on the designs it is given. Checkpoints are small JSON files. Picklable.
    `cap` bounds the logits: an unbounded softmax saturates (after a few rounds a specialist's other behaviours
    weigh e^-6 and it can no longer re-learn), which a PPO policy fine-tuned on new designs does not; adaptive
    K's challengers start from their parent and must be able to diverge, so its landscapes cap at 2 (the best
    behaviour then weighs >= 0.98 of the mixture) [ours]."""
    space: Box
    sites: np.ndarray
    width: float = 0.3
    n_designs: int = 64
    steps: int = 25
    lr: float = 5.0
    cap: float | None = None

    def quality(self, x_unit: np.ndarray) -> np.ndarray:
        d2 = ((np.atleast_2d(x_unit)[:, None, :] - np.asarray(self.sites)[None]) ** 2).sum(-1)
        return np.exp(-d2 / (2 * self.width ** 2))

    def region(self, x_unit: np.ndarray) -> np.ndarray:
        return np.argmax(self.quality(x_unit), axis=1)

    def policy(self, ckpt: str | None) -> np.ndarray:
        if ckpt is None:
            return np.zeros(len(self.sites))
        with open(ckpt) as fh:
            return np.array(json.load(fh)["p"])

    def train(self, k, round, sampler, ckpt_in, ckpt_out):
        rng, p = np.random.default_rng(sampler.seed), self.policy(ckpt_in)
        for _ in range(self.steps):
            qbar = self.quality(self.space.to_unit(sampler(rng, self.n_designs))).mean(axis=0)
            pi = np.exp(p - p.max())
            pi /= pi.sum()
            p = p + self.lr * pi * (qbar - pi @ qbar)  # d/dp of sum_b softmax(p)_b qbar_b
            p = p if self.cap is None else np.clip(p, -self.cap, self.cap)
        write_json(ckpt_out, {"p": p.tolist(), "k": k, "round": round})

    def score(self, k, ckpt, designs):
        p = self.policy(ckpt)
        pi = np.exp(p - p.max())
        return self.quality(self.space.to_unit(designs)) @ (pi / pi.sum())


DEMO_SITES_2D = np.array([[0.15, 0.2], [0.85, 0.35], [0.4, 0.85]])
SITES = 1000   # stream id of planted sites (apart from GES's own streams)


def planted_sites(B: int, dim: int, seed: int) -> np.ndarray:
    """B sites in [0.1, 0.9]^dim drawn from the seed, each at least 0.7 x (0.8^dim / B)^(1/dim) from the
    others (70 % of the spacing of B evenly spread sites), so that every site is its own behaviour's region
    and not a copy of a neighbour's [ours]."""
    if not (isinstance(B, (int, np.integer)) and B >= 1):
        raise ValueError(f"sites={B!r} not allowed: an integer >= 1")
    rng, sep = rng_for(seed, SITES), 0.7 * (0.8 ** dim / B) ** (1.0 / dim)
    for _ in range(1000):   # restart when the sites drawn so far leave no room
        sites = []
        for _ in range(200 * B):
            x = rng.uniform(0.1, 0.9, dim)
            if all(np.linalg.norm(x - y) >= sep for y in sites):
                sites.append(x)
                if len(sites) == B:
                    return np.array(sites)
    raise RuntimeError(f"no {B} sites {sep:.2f} apart found in [0.1, 0.9]^{dim}")


def planted(B: int, dim: int, seed: int) -> PlantedLandscape:
    """Adaptive K's test landscape: B planted sites (planted_sites), width 0.2, logits capped at 2 [ours]."""
    space = Box([f"theta_{i + 1}" for i in range(dim)], [0.0] * dim, [1.0] * dim)
    return PlantedLandscape(space, planted_sites(B, dim, seed), width=0.2, cap=2.0)


def demo_landscape(dim: int) -> tuple[PlantedLandscape, int]:
    """The demo's landscape and K: three planted sites in 2-D with K = 3, six in 3-D with K = 6."""
    space = Box([f"theta_{i + 1}" for i in range(dim)], [0.0] * dim, [1.0] * dim)
    K = 3 if dim == 2 else 6
    return PlantedLandscape(space, DEMO_SITES_2D if dim == 2 else rng_for(12345).uniform(0.1, 0.9, (K, 3))), K


def routed_mean(res: GESResult, land: PlantedLandscape, n: int = 2000, seed: int = 0) -> float:
    """Mean score of n uniform test designs, each scored by the specialist the density router picks (eq. 10)."""
    designs = res.space.sample_uniform(rng_for(seed, SITES, 1), n)
    return float(np.mean(routed_evaluator(res, land.score, "density")(designs)))


def draw_territories(res: GESResult, out_dir: str, land: PlantedLandscape) -> str:
    """out_dir/territories.png (report.figures.plot_territories), the planted regions shaded in 2-D."""
    return plot_territories(res.history, os.path.join(out_dir, "territories.png"),
                            background=land.region if res.space.d == 2 else None)


def demo_adaptive(out_dir: str, K: str | int = "auto", B: int = 3, dim: int = 2, seed: int = 0,
                  workers: int = 1, max_rounds: int = 20) -> tuple:
    """GES on planted(B, dim, seed) with adaptive K (K = "auto", starting at K_max: merging takes a round,
    splitting three, docs/ges_adaptive) or a fixed K; writes out_dir/territories.png. Returns (result, mean
    score of routed_mean)."""
    land = planted(B, dim, seed)
    if K == "auto":
        cfg = GESConfig(K=GESConfig.K_max, adaptive=True, max_rounds=max_rounds)
    else:
        cfg = GESConfig(K=int(K), max_rounds=max_rounds)
    ex = SerialExecutor() if workers <= 1 else ProcessPoolExecutor(workers)
    with ex:
        res = run_ges(land.space, land.train, land.score, out_dir, cfg, seed, ex, progress=None)
    draw_territories(res, out_dir, land)
    return res, routed_mean(res, land, seed=seed)


def demo(out_dir: str, dim: int = 2, seed: int = 0, workers: int = 1) -> GESResult:
    """Run GES on the planted landscape (a 2-D box with K=3, or 3-D with K=6); write out_dir/territories.png."""
    land, K = demo_landscape(dim)
    ex = SerialExecutor() if workers <= 1 else ProcessPoolExecutor(workers)
    with ex:
        res = run_ges(land.space, land.train, land.score, out_dir, GESConfig(K=K), seed, ex)
    print(f"wrote {draw_territories(res, out_dir, land)}")
    return res


def rounds_to_coverage(dim: int, n_init: int, n_probe: int, seeds=(0, 1, 2), max_rounds: int = 20) -> list:
    """Rounds GES takes to reach its target coverage on the planted landscape (K = 3 in 2-D, 6 in 3-D), per
    seed, as (rounds, final coverage). Why: coverage grows by refitting each territory to its designs, n_init
    seeds plus the probes it wins, so its growth per round is set by F / n_init, not by F alone; this measures
    what a preset's probe budget buys (`python ges.py sweep`)."""
    land, K = demo_landscape(dim)
    out = []
    for seed in seeds:
        cfg = GESConfig(K=K, n_init_designs=n_init, n_probe=n_probe, max_rounds=max_rounds)
        with tempfile.TemporaryDirectory() as d:
            res = run_ges(land.space, land.train, land.score, d, cfg, seed, SerialExecutor(), progress=None)
        out.append((res.rounds, res.coverage))
    return out


def sweep(pairs=((50, 100), (50, 16), (50, 4), (16, 32), (8, 16), (8, 8))):
    """Print rounds to coverage for (n_init, F) pairs: the facts' (50, 100), smaller budgets, and the same
    F / n_init ratio at smaller sizes."""
    for dim in (2, 3):
        for n_init, F in pairs:
            r = rounds_to_coverage(dim, n_init, F)
            print(f"D{dim} (K={3 if dim == 2 else 6})  n_init {n_init:3d}  F {F:3d}  F/n_init {F / n_init:5.2f}: "
                  f"rounds {[x[0] for x in r]}, final coverage {[round(x[1], 2) for x in r]}", flush=True)


# ---------------------------------------------------------------------------------------------------------
# 2. Benchmark and command line
# ---------------------------------------------------------------------------------------------------------
def _best_time(fn, repeats: int = 7, loops: int = 5) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(loops):
            fn()
        best = min(best, (time.perf_counter() - t0) / loops)
    return best


def bench() -> dict:
    """Time one coverage estimate (N_mc = 10^4, K = 6, d = 3) and one routing of 10^4 points, next to a
    reference measured in the same run: plain numpy density of ONE Gaussian on the same points."""
    rng = rng_for(0)
    pts, mu, sigma = rng.random((10_000, 3)), rng.random((6, 3)), 0.05 + 0.2 * rng.random((6, 3))
    ref = _best_time(lambda: np.exp(-0.5 * (((pts - mu[0]) / sigma[0]) ** 2).sum(1)) / np.prod(sigma[0]))
    t = {"reference_one_gaussian": ref, "coverage_K6": _best_time(lambda: coverage(mu, sigma, pts)),
         "route_K6": _best_time(lambda: route_unit(pts, mu, sigma))}
    for name, s in t.items():
        print(f"{name:24s} {1e3 * s:8.3f} ms   ({s / ref:5.1f} x reference)")
    return t


OLD_FLAGS = {"--demo": ("demo", True), "--sweep": ("sweep", False), "--bench": ("bench", False)}   # deprecated


def parser() -> argparse.ArgumentParser:
    ap = args.program("python ges.py", __doc__, "ges.py -- GES on a synthetic landscape (no robot), and its benchmark")
    sub = ap.add_subparsers(dest="cmd", required=True)
    d = args.command(sub, "demo", "run GES on the synthetic landscape, write OUT/territories.png", __doc__)
    d.add_argument("--out", required=True, metavar="OUT", help="the run's folder")
    d.add_argument("--dim", type=int, default=2, choices=(2, 3), help="dimension of the demo box")
    d.add_argument("--seed", type=int, default=0, help="an integer >= 0")
    args.add_workers(d, "processes, >= 1 (> 1: a ProcessPoolExecutor)")
    d.add_argument("--K", help="on a landscape of --sites sites: 'auto' (adaptive K, ges.py section 8, starting at "
                   "K_max = 8) or a fixed K >= 1")
    d.add_argument("--sites", type=int, help="planted sites B >= 1 drawn from --seed (default 3 with --K)")
    args.command(sub, "sweep", "rounds to 95 %% coverage per (n_init, F), planted landscape, seeds 0-2", __doc__)
    args.command(sub, "bench", "time coverage and routing", __doc__)
    return ap


def main(argv=None) -> int:
    """The command line of `python ges.py` and of this module; a bad argument is one line naming it and its
    allowed values (exit 2), checked before anything is written; a failed demo leaves no folder it created
    behind."""
    a = args.parse(parser(), argv, OLD_FLAGS)
    if a.cmd == "bench":
        bench()
        return 0
    if a.cmd == "sweep":
        sweep()
        return 0
    made = None
    try:
        if a.seed < 0:
            raise ValueError(f"--seed {a.seed} must be an integer >= 0")
        if a.workers < 1:
            raise ValueError(f"--workers {a.workers} must be an integer >= 1")
        if a.K is not None and a.K != "auto" and not (a.K.isdigit() and int(a.K) >= 1):
            raise ValueError(f"--K {a.K} must be 'auto' or an integer >= 1")
        if a.sites is not None and a.sites < 1:
            raise ValueError(f"--sites {a.sites} must be an integer >= 1")
        if not a.out.strip():
            raise ValueError("--out needs a folder name")
        out = os.path.abspath(a.out)
        if os.path.exists(out) and not os.path.isdir(out):
            raise ValueError(f"--out {a.out} exists and is not a folder")
        made = None if os.path.exists(out) else out
        try:
            os.makedirs(out, exist_ok=True)
            if not os.access(out, os.W_OK):
                raise PermissionError("read-only")
        except OSError as e:
            raise OSError(f"--out {a.out}: cannot write there ({e.strerror or e})") from None
        if a.K is None and a.sites is None:
            demo(a.out, a.dim, a.seed, a.workers)
            return 0
        res, m = demo_adaptive(a.out, a.K or "auto", a.sites or 3, a.dim, a.seed, a.workers)
        for h in res.history["rounds"][1:]:
            events = "; ".join(f"{e['kind']} {e['id']}->{e.get('into', e.get('child'))}: {e['reason']}"
                               for e in h.get("events", []))
            print(f"round {h['round']:2d}: K {len(h['mu'])}, coverage {h['coverage']:.1%}"
                  + (f"  ({events})" if events else ""))
        print(f"wrote {os.path.join(a.out, 'territories.png')}")
        print(f"final K = {len(res.ckpt)}, coverage = {100 * res.coverage:.1f} %, mean score = {m:.4f}")
        return 0
    except (ValueError, OSError) as e:   # bad arguments, an unwritable folder, a run_dir of another run
        if made and os.path.isdir(made):
            shutil.rmtree(made, ignore_errors=True)
        print(f"ges.py: error: {str(e).splitlines()[0]}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
