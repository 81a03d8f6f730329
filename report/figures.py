"""The figures' plotting and measuring helpers that need no run: Fig. 7, learning curves, toe-height traces
and the gait features Fig. 5's claim is measured by. run_all.py's figure stage feeds them a run's numbers."""
from __future__ import annotations

import os
from dataclasses import replace

import numpy as np

import ballu
from report.paper import PAPER_KSENS_PEAK_K
from runkit.files import redo_if_damaged
from runkit.logs import read_log


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def toe_heights(policy, design_full, task: str = "obstacle", level: int = 30, steps: int | None = None) -> np.ndarray:
    """Left/right toe z (steps, 2) over one episode of `steps` control steps (None: the env's; a run passes its
    preset's): a 1-lane BalluEnv, toe tips from the env's own state. The time limit is one step longer than the
    episode, so the last sample is not taken after an automatic reset."""
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
    if "auto" in ks:   # adaptive K (ges.py section 7b): its mean as a line, marked at the K it ended with
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
