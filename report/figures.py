"""The figures and what they measure, drawn from the numbers, policies and files a caller hands them (run_all.py's
figure stage feeds them a run's): Fig. 3's score distributions, Fig. 4's experts, Fig. 5's toe heights and the
gait features its claim is measured by, GES's territories (Fig. 6), Fig. 7, Fig. 8's design sensitivity and
learning curves. ballu is imported by the helpers that run the robot, so the territory figure
(which experiments/ges_demo.py draws too) needs none."""
from __future__ import annotations

import math
import os
from dataclasses import replace
from typing import Callable

import numpy as np

from ges import CKPT_DIR, farthest_point_sampling
from runkit.box import Box
from report.paper import METHOD_NAMES, PAPER_KSENS_PEAK_K, PAPER_TABLE2
from runkit.files import redo_if_damaged
from runkit.logs import read_log

COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf"]   # specialist k


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def distinct_designs(space, n: int, seed: int) -> np.ndarray:
    """n designs from distinct regions of `space` (a ballu.DesignSpace or a ges.Box): farthest point sampling on a
    uniform pool (as GES's own init)."""
    rng = np.random.default_rng(seed)
    pts = farthest_point_sampling(rng.random((2000, space.d)), n, rng)
    return Box.of(space).from_unit(pts[np.lexsort(pts.T[::-1])])


def fig_distributions(cells: dict, tasks, spaces, methods, units: dict, K: dict, path: str) -> str:
    """Fig. 3: score distribution per method on the test designs, per task and space; paper means as red x.
    `cells`: Table II's, keyed "task-space", each method's scores; `K`: specialists per space."""
    plt = _plt()
    fig, axes = plt.subplots(2, 2, figsize=(10, 7.5))
    for i, t in enumerate(tasks):
        for j, s in enumerate(spaces):
            if f"{t}-{s}" not in cells:   # a run of some cells only (Preset.cells)
                axes[i, j].axis("off")
                continue
            ax, cell = axes[i, j], cells[f"{t}-{s}"]
            data = [cell[m]["scores"] for m in methods]
            ax.boxplot(data, showmeans=True, meanprops=dict(marker="o", mfc="k", mec="k", ms=5))
            for k, m in enumerate(methods):
                jitter = np.random.default_rng(k).uniform(-0.12, 0.12, len(data[k]))
                ax.plot(k + 1 + jitter, data[k], ".", alpha=0.35, color="C0")
                paper = PAPER_TABLE2[(t, s)].get(m)
                if paper is not None:
                    ax.plot(k + 1, paper, "rx", ms=9, mew=2)
            ax.set_xticks(range(1, len(methods) + 1), [METHOD_NAMES[m] for m in methods], fontsize=8)
            ax.set_ylabel(f"J [{units[t]}]")
            ax.set_title(f"{t}, {s.upper()} (K={K[s]}), {len(data[0])} test designs", fontsize=10)
    fig.suptitle("Fig. 3: performance distributions (box; black dot = our mean; red x = paper mean)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def fig_experts(moe, router, space, theta, cell: str, path: str) -> tuple:
    """Fig. 4: expert contributions on designs from distinct regions (`theta`, coordinates of `space`): the e2e
    MoE's soft gate weights vs GES's density router (`router`, a ges.GESResult: a hard choice) in the cell named
    `cell`; gate entropy normalised by log K. Returns (path, that entropy, the gate weights, the routes)."""
    import ballu
    plt = _plt()
    full = space.full(theta)
    gate = moe.gate_weights(ballu.normalise_design(full).astype(np.float32))
    ks = router.route(theta)
    hard = np.eye(len(router.ckpt))[ks]
    ent = float(np.mean(-(gate * np.log(np.clip(gate, 1e-12, 1))).sum(1)) / math.log(gate.shape[1]))
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.4), layout="constrained")
    labels = [" ".join(f"{v:.3g}" for v in row) for row in theta]
    for ax, w, title in ((axes[0], gate, f"e2e MoE gate weights (normalised entropy {ent:.2f})"),
                         (axes[1], hard, "GES density router (entropy 0)")):
        im = ax.imshow(w, vmin=0, vmax=1, cmap="viridis", aspect="auto")
        ax.set_yticks(range(len(labels)), labels if ax is axes[0] else [""] * len(labels), fontsize=7)
        ax.set_xticks(range(w.shape[1]), [f"E{k}" for k in range(w.shape[1])])
        ax.set_xlabel("expert / specialist")
        ax.set_title(title, fontsize=10)
        for (a, b), v in np.ndenumerate(w):
            ax.text(b, a, f"{v:.2f}", ha="center", va="center", fontsize=6, color="w" if v < 0.5 else "k")
    axes[0].set_ylabel(" ".join(space.names))
    fig.colorbar(im, ax=axes, shrink=0.8)
    fig.suptitle(f"Fig. 4: expert contributions on {len(theta)} distinct designs ({cell})")
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path, ent, gate.tolist(), ks.tolist()


GAIT_DESIGNS = 8   # [ours] common designs on which every specialist's gait is measured (Fig. 5's claim)


def specialist_gaits(experts: list, space, seed: int, task: str = "obstacle", level: int = 30,
                     steps: int | None = None) -> dict:
    """Fig. 5's claim as a number: every specialist of a GES run (`experts`, its policies) plays one episode of
    `steps` control steps on the same GAIT_DESIGNS designs of `space` (distinct_designs by `seed`) facing the
    level-30 obstacle; per gait feature, a Friedman test (designs as blocks) of whether the specialists differ.
    'Specialists behave differently' is supported if some feature differs at p < 0.05 / len(GAIT_FEATURES)
    (Bonferroni). Needs K >= 3 (Friedman)."""
    import ballu
    from scipy.stats import friedmanchisquare

    from report.tables import GAIT_FEATURES
    designs = space.full(distinct_designs(space, GAIT_DESIGNS, seed))
    dt = ballu.BalluConfig().control_dt
    feats = [[gait_features(toe_heights(e, d[None], task, level, steps), dt) for d in designs] for e in experts]
    out = {"K": len(experts), "designs": len(designs), "features": {}}
    for f in GAIT_FEATURES:
        table = np.array([[g[f] for g in per_design] for per_design in feats])   # (K, designs)
        same = np.all(table == table[0])
        p = 1.0 if same or len(experts) < 3 else float(friedmanchisquare(*table).pvalue)
        out["features"][f] = {"mean": table.mean(axis=1).tolist(), "p": p}
    return out


def fig_toes(experts: list, design_full, path: str, steps: int | None = None) -> str:
    """Fig. 5: toe heights of a GES run's specialists (`experts`, the run's policies) on one full design (the GES
    peak) at a 30 cm obstacle (level 30 = 30.1 cm) at x = 0.5 m, episodes of `steps` control steps."""
    import ballu
    plt = _plt()
    fig, axes = plt.subplots(2, 1, figsize=(8, 5), sharex=True)
    dt = ballu.BalluConfig().control_dt
    for k, expert in enumerate(experts):
        z = toe_heights(expert, design_full, steps=steps)
        tt = np.arange(len(z)) * dt
        for side in range(2):
            axes[side].plot(tt, 100 * z[:, side], color=COLORS[k % len(COLORS)], label=f"specialist {k}")
    for side, name in enumerate(("left", "right")):
        axes[side].axhline(30.1, color="gray", ls="--", lw=1)
        axes[side].set_ylabel(f"{name} toe z [cm]")
    axes[1].set_xlabel("time [s]")
    axes[0].legend(fontsize=8)
    fig.suptitle(f"Fig. 5: toe heights of {len(experts)} GES specialists on design "
                 f"{np.round(design_full[0], 4).tolist()} facing a 30 cm obstacle (dashed)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def fig_sensitivity(panels: list, path: str) -> str:
    """Fig. 8: the GES score over D2 for each task, interpolated between the test designs (dots). `panels`: per
    task, (task, its D2 space, the test designs in its coordinates, GES's scores on them, the score's unit)."""
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, (t, space, th, z, unit) in zip(axes, panels):
        z = np.array(z)
        if len(z) >= 4 and np.ptp(z) > 0:
            try:
                cs = ax.tricontourf(th[:, 0], th[:, 1], z, levels=12, cmap="viridis")
                fig.colorbar(cs, ax=ax, label=f"J [{unit}]")
            except (ValueError, RuntimeError):   # degenerate triangulation: dots only
                pass
        sc = ax.scatter(th[:, 0], th[:, 1], c=z, cmap="viridis", edgecolors="k", s=25)
        if len(z) < 4 or np.ptp(z) == 0:
            fig.colorbar(sc, ax=ax, label=f"J [{unit}]")
        ax.set(xlabel="GCR", ylabel="SPCF", xlim=(space.lo[0], space.hi[0]), ylim=(space.lo[1], space.hi[1]),
               title=f"{t}: GES score over D2 ({len(z)} test designs)")
    fig.suptitle("Fig. 8: design sensitivity of GES performance")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def ges_logs(run_dir: str) -> list:
    """A GES run's learning curves for fig_curves: each specialist's per-round CSVs, in round order (steps are
    cumulative across rounds); specialists by the ids in the file names (adaptive K's challengers count on past K)."""
    ck = os.path.join(run_dir, CKPT_DIR)
    files = [f for f in (sorted(os.listdir(ck)) if os.path.isdir(ck) else []) if f.endswith(".csv")]
    ids = sorted({int(f[len("spec"):].split("_")[0]) for f in files if f.startswith("spec")})
    return [(f"specialist {k}", [os.path.join(ck, f) for f in files if f.startswith(f"spec{k}_")]) for k in ids]


def toe_heights(policy, design_full, task: str = "obstacle", level: int = 30, steps: int | None = None) -> np.ndarray:
    """Left/right toe z (steps, 2) over one episode of `steps` control steps (None: the env's; a run passes its
    preset's): a 1-lane BalluEnv, toe tips from the env's own state. The time limit is one step longer than the
    episode, so the last sample is not taken after an automatic reset."""
    import ballu
    cfg = ballu.policy_config(policy, task)   # the observation it trained with
    steps = steps or cfg.episode_steps
    env = ballu.BalluEnv(1, replace(cfg, episode_steps=steps + 1), curriculum=False)
    try:
        obs, _ = env.reset(seed=0, options={"designs": design_full, "levels": level})
        z = []
        for _ in range(steps):
            obs, *_ = env.step(policy(obs))
            z.append(env.read_lanes().toe[0, :, 2])
    finally:
        env.close()
    return np.array(z)


def gait_features(z: np.ndarray, dt: float) -> dict:
    """What a toe trajectory (steps, 2) says of a gait [ours]: the highest the lower toe gets (cm), the dominant
    frequency of the mean toe height (Hz, from its spectrum without the mean), and the share of control steps
    with both toes more than 2 cm up (%)."""
    low = z.min(axis=1)
    mean = z.mean(axis=1) - z.mean()
    freqs = np.fft.rfftfreq(len(mean), dt)
    spectrum = np.abs(np.fft.rfft(mean))
    return {"peak_toe_cm": float(100 * low.max()), "step_hz": float(freqs[1:][np.argmax(spectrum[1:])]),
            "airborne_pct": float(100 * np.mean(low > 0.02))}


def fig_ksens(ks: dict, path: str) -> str:
    """Fig. 7: GES mean score (+- std over test designs) against K; adaptive K ("auto") as a line if it ran."""
    plt = _plt()
    K = sorted(int(k) for k in ks if k != "auto")
    m, sd = [ks[str(k)]["mean"] for k in K], [ks[str(k)]["std"] for k in K]
    fig, ax = plt.subplots(figsize=(5, 3.5))
    ax.errorbar(K, m, yerr=sd, fmt="o-", capsize=3, label="ours (mean +- std over test designs)")
    if "auto" in ks:   # adaptive K (ges.py section 8): its mean as a line, marked at the K it ended with
        a = ks["auto"]
        ax.axhline(a["mean"], color="purple", ls=":", lw=1)
        ax.plot([a["final_K"]], [a["mean"]], "s", color="purple", label=f"adaptive K (ends at K={a['final_K']})")
    ax.axvline(PAPER_KSENS_PEAK_K, color="r", ls="--", lw=1, label=f"paper: peak at K={PAPER_KSENS_PEAK_K}")
    ax.set(xlabel="K (specialists)", ylabel="GES mean J [cm]", title="Fig. 7: K sensitivity (obstacle, D2)",
           xticks=sorted(set(K) | {PAPER_KSENS_PEAK_K} | ({ks["auto"]["final_K"]} if "auto" in ks else set())))
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def level_of(task: str, score: float) -> int:
    """Invert ballu.level_score: the curriculum level a score J stands for (the nearest one)."""
    import ballu
    levels = np.arange(ballu.MAX_LEVEL + 1)
    return int(levels[np.argmin(np.abs(ballu.level_score(task, levels) - score))])


def fig_curves(logs: list, path: str, title: str) -> str:
    """Learning curves (episode return, curriculum level vs control steps) of several policies in one figure."""
    plt = _plt()
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.4))
    for label, csv_paths in logs:
        parts = [redo_if_damaged(c, read_log, "learning-curve CSV", "its curve is left out") for c in csv_paths
                 if os.path.exists(c) and os.path.getsize(c) > 0]
        parts = [p for p in parts if p is not None and len(p["steps"])]
        if not parts:
            continue
        d = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        ax[0].plot(d["steps"], d["episode_return"], label=label)
        ax[1].plot(d["steps"], d["mean_level"], label=label)
    ax[0].set(xlabel="control steps", ylabel="episode return (last 100)")
    ax[1].set(xlabel="control steps", ylabel="mean curriculum level")
    ax[1].legend(fontsize=7, loc="best")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _snapshots(n_rounds: int, n: int = 4) -> list:
    return sorted(set(int(round(i)) for i in np.linspace(0, n_rounds - 1, min(n, n_rounds))))


def plot_territories(history: dict, path: str, background: Callable | None = None) -> str:
    """Territory evolution: 2-sigma ellipses (the coverage contour of eq. 8) at a few rounds, with the probes
    of that round coloured by winner and each centre's trail; pairwise projections when d = 3; plus coverage
    and wins per round. `history` is the dict of history.json (or GESResult.history). `background(x_unit)`
    -> int labels may shade planted regions (2-D only). Uses matplotlib's Agg canvas, no pyplot state."""
    from matplotlib.figure import Figure
    from matplotlib.patches import Ellipse

    space, rounds = Box.from_dict(history["space"]), history["rounds"]
    lo, hi, d = space.lo, space.hi, space.d
    pairs = [(0, 1)] if d == 2 else [(i, j) for i in range(d) for j in range(i + 1, d)]
    snaps = _snapshots(len(rounds))
    ids_of = lambda h: h.get("ids", list(range(len(h["mu"]))))          # noqa: E731  (ges.py section 8)
    trained_of = lambda h: h.get("ids_trained", ids_of(h))              # noqa: E731  the winners' index space
    fig = Figure(figsize=(3.3 * (len(snaps) + 1), 3.1 * len(pairs) + 0.4), layout="constrained")
    axes = fig.subplots(len(pairs), len(snaps) + 1, squeeze=False)
    K0, K1 = len(rounds[0]["mu"]), len(rounds[-1]["mu"])
    for r_i, (i, j) in enumerate(pairs):
        for c_i, s in enumerate(snaps):
            ax, h = axes[r_i, c_i], rounds[s]
            if background is not None and d == 2:  # planted regions: light fill + dashed borders
                g = np.linspace(0, 1, 300)
                gx, gy = np.meshgrid(g, g)
                lab = background(np.stack([gx.ravel(), gy.ravel()], 1)).reshape(gx.shape)
                px, py = lo[0] + gx * (hi[0] - lo[0]), lo[1] + gy * (hi[1] - lo[1])
                levels = np.arange(lab.max() + 2) - 0.5
                ax.contourf(px, py, lab, levels=levels, cmap="Greys", vmin=-1, vmax=3 * lab.max() + 3)
                ax.contour(px, py, lab, levels=levels[1:-1], colors="k", linewidths=0.8, linestyles="--")
            probes = space.from_unit(np.array(h["probes_unit"]).reshape(-1, d))
            for k, sid in enumerate(ids_of(h)):   # colour by id: a specialist keeps its colour through merges
                col = COLORS[sid % len(COLORS)]
                mu, sg = np.array(h["mu"][k]), np.array(h["sigma"][k])
                ax.add_patch(Ellipse((mu[i], mu[j]), 4 * sg[i], 4 * sg[j], fc=col, ec=col, alpha=0.18, lw=0))
                ax.add_patch(Ellipse((mu[i], mu[j]), 4 * sg[i], 4 * sg[j], fc="none", ec=col, lw=1.6))
                trail = np.array([rounds[t]["mu"][ids_of(rounds[t]).index(sid)] for t in range(s + 1)
                                  if sid in ids_of(rounds[t])])
                ax.plot(trail[:, i], trail[:, j], "-", color=col, lw=0.8, alpha=0.7)
                ax.plot(mu[i], mu[j], "o", color=col, mec="k", ms=6)
            for k, sid in enumerate(trained_of(h)):
                won = np.array(h["winner"]) == k
                if won.any():   # black-edged, above the ellipses: a probe is one point, it must stand out
                    ax.plot(probes[won, i], probes[won, j], "D", color=COLORS[sid % len(COLORS)], ms=4.5, mec="k",
                            mew=0.6, zorder=4)
            ax.set_xlim(lo[i], hi[i])
            ax.set_ylim(lo[j], hi[j])
            ax.set_xlabel(space.names[i])
            ax.set_ylabel(space.names[j])
            if r_i == 0:
                ax.set_title(f"round {h['round']}: coverage {h['coverage']:.0%}", fontsize=10)
        axes[r_i, -1].axis("off")
    ax = axes[0, -1]
    ax.axis("on")
    t = [h["round"] for h in rounds]
    ax.plot(t, [100 * h["coverage"] for h in rounds], "k.-", label="MC coverage", zorder=3)   # above the bars
    ax.axhline(100 * history["config"]["target_coverage"], color="gray", ls="--", lw=1, label="target")
    every = sorted({sid for h in rounds for sid in trained_of(h)} | set(ids_of(rounds[0])))
    wins = np.array([[dict(zip(trained_of(h), h["wins"])).get(sid, 0) for sid in every] for h in rounds])
    bottom = np.zeros(len(t))
    for c, sid in enumerate(every):
        share = 100 * wins[:, c] / np.maximum(wins.sum(1), 1)
        ax.bar(t, share, bottom=bottom, color=COLORS[sid % len(COLORS)], alpha=0.35, width=0.8,
               label=f"specialist {sid} wins")
        bottom += share
    if any("events" in h for h in rounds):   # adaptive K: K per round, splits and merges marked
        ax2 = ax.twinx()
        ks = [len(h["mu"]) for h in rounds]
        ax2.plot(t, ks, "-", color="purple", lw=1.2, label="K (right axis)")
        for kind, mark in (("split", "^"), ("merge", "v")):
            at = [(h["round"], len(h["mu"])) for h in rounds for e in h.get("events", []) if e["kind"] == kind]
            if at:
                ax2.plot(*zip(*at), mark, color="purple", ms=7, ls="none", label=f"{kind} (right axis)")
        ax2.set_ylim(0, max(ks) + 1)
        ax2.set_ylabel("K")
        h2, l2 = ax2.get_legend_handles_labels()
    else:
        h2, l2 = [], []
    ax.set_ylim(0, 105)
    ax.set_xticks(t)
    ax.set_xlabel("round")
    ax.set_ylabel("coverage %  /  share of probes won")
    ax.set_title("coverage and wins per round", fontsize=10)
    handles, labels = ax.get_legend_handles_labels()
    handles, labels = handles + h2, labels + l2
    if len(pairs) > 1:  # 3-D: the legend gets its own (otherwise empty) cell
        axes[1, -1].legend(handles, labels, loc="center", fontsize=9)
    else:   # 2-D: below the panel, where it covers neither the coverage line nor the bars
        ax.legend(handles, labels, fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2)
    fig.suptitle(f"GES territories (2-sigma ellipses, diamonds: probes won this round), "
                 + (f"K={K0}" if K0 == K1 and "events" not in rounds[-1] else f"adaptive K: {K0} -> {K1}")
                 + f", d={d}"
                 + ("; grey/dashed: planted regions" if background is not None and d == 2 else ""))
    fig.savefig(path, dpi=110)
    return path


# ---------------------------------------------------------------------------------------------------------
