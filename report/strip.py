"""report/strip.py -- the motion strip of paper Fig. 1: one episode of a policy on a design, filmed from the side.

run_all.py's figure stage films the best design each task's GES search found; `python ballu.py strip --out PNG`
films a pump gait (experiments/ballu_bench.py), `python -m experiments.ppo_ballu strip` a trained policy.
"""
from __future__ import annotations

import numpy as np

from ballu import BASELINE, BalluEnv, PumpGait, level_score, policy_config, task_geometry


def motion_strip(path, policy=None, task="obstacle", level=30, design=BASELINE, frames=8, cfg=None,
                 width=360, height=300):
    """Play one episode with PyBullet's CPU renderer and save `frames` side views as one PNG (paper Fig. 1)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    policy = policy or PumpGait(12)
    cfg = policy_config(policy, task, cfg)
    env = BalluEnv(1, cfg, curriculum=False)
    obs, _ = env.reset(seed=0, options={"designs": design, "levels": level})
    keep = set(np.linspace(0, cfg.episode_steps - 1, frames).astype(int).tolist())
    shots, xs = [], []
    p, b = env.client(0), env.bodies[0]
    g = task_geometry(task)
    for t in range(cfg.episode_steps):
        if t in keep:
            x = p.getBasePositionAndOrientation(b)[0][0]
            view = p.computeViewMatrix([x, -3.2, 0.9], [x, 0, 0.7], [0, 0, 1])
            proj = p.computeProjectionMatrixFOV(50, width / height, 0.1, 10)
            img = p.getCameraImage(width, height, view, proj, renderer=p.ER_TINY_RENDERER,
                                   lightDirection=[-1, -2, 3], shadow=0)[2]
            shots.append(np.reshape(img, (height, width, 4))[:, :, :3])
            xs.append(x)
        obs, *_, info = env.step(policy(obs))
    env.close()
    fig, axes = plt.subplots(1, frames, figsize=(2.2 * frames, 2.4))
    for ax, im, t, x in zip(axes, shots, sorted(keep), xs):
        ax.imshow(im)
        ax.set_title(f"t={t * cfg.control_dt:.1f}s  x={x:.2f}m", fontsize=8)
        ax.axis("off")
    h = level_score(task, level)
    unit = "cm obstacle" if task == "obstacle" else "deg ramp"
    fig.suptitle(f"BALLU {task}, level {level} ({h:.1f} {unit}), design l_f,l_t,gcr,spcf = "
                 f"{np.round(np.asarray(design, float), 4).tolist()}; terrain x {g['x0']}..{g['x1']} m, "
                 f"goal x {g['goal']} m", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
