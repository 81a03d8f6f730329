"""The project's tests, one file grouped by module: ballu.py, ppo.py, ges.py, tpe.py, run_all.py, runkit/, report/.

Run: pytest -q test_ges.py
"""
import contextlib
import csv as csv_module
import functools
import glob
import hashlib
import json
import math
import os
import pickle
import re
import shutil
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace

import numpy as np
import pybullet
import pytest
import torch
from scipy import stats
from scipy.stats import multivariate_normal

import ballu
import ges
import ppo
from codesign import policies
import run_all
from experiments import ballu_capability, ges_demo, ppo_ballu, ppo_protocol, probe_agreement, use
from report import animate, figures, tables
from runkit import cli, logs, plan, pool, progress
from runkit import stats as rstats
from runkit.clock import StageClock
from runkit.folder import check_output, open_output
from ballu import BASELINE, BalluConfig, BalluEnv
from tpe import TPE, Parzen, TPEConfig, bandwidths, build_parzen, n_good, optimize, recency_weights

def read_json(path):
    with open(path) as f:
        return json.load(f)


def read_text(path):
    with open(path) as f:
        return f.read()


def read_bytes(path, n: int = -1) -> bytes:
    with open(path, "rb") as f:
        return f.read(n)


def write_bytes(path, data: bytes):
    with open(path, "wb") as f:
        f.write(data)


# ==========================================================================================================
# ballu.py: physics sanity, lanes, determinism, curriculum, bad input
# ==========================================================================================================
D_MID = ballu.D2_CENTRE


def robot_com(env, i=0):
    """Mass-weighted centre of mass of lane i's robot (base + every link's centre of mass) and its mass."""
    p, b = env.client(i), env.bodies[i]
    ms, xs = [p.getDynamicsInfo(b, -1)[0]], [np.array(p.getBasePositionAndOrientation(b)[0])]
    for link in range(5):
        ms.append(p.getDynamicsInfo(b, link)[0])
        xs.append(np.array(p.getLinkState(b, link)[0]))
    return np.average(xs, axis=0, weights=ms), sum(ms)


def test_ballu_mass_matches_facts():
    # docs/facts.md: total mass 0.198 kg (0.480/0.443), 0.185 kg (0.286/0.215); balloon about 0.095 kg
    for lf, lt, m in ((0.480, 0.443, 0.198), (0.286, 0.215, 0.185)):
        assert ballu.mass_properties([lf, lt, 0.8, 0.01])["total"] == pytest.approx(m, abs=0.0015)
    assert ballu.mass_properties(BASELINE)["balloon"][0] == pytest.approx(0.095, abs=0.001)


@pytest.mark.parametrize("gcr", [0.72, 0.90])
def test_ballu_buoyancy_free_fall_accelerates_at_one_minus_gcr_g(gcr):
    """Held clear of the ground and released from rest, the centre of mass falls at (1 - gcr) g.

    Drag is switched off (it is tested on its own below); a is the quadratic term of a least-squares fit
    of the centre of mass height over 40 physics steps (0.2 s). Passive joints wobble a little, which moves
    single 5-step second differences by up to 5 %; the fit averages that out. Tolerance 1.5 %.
    """
    cfg = replace(BalluConfig(), start_z=3.0, drag_coef=0.0)
    env = BalluEnv(1, cfg)
    env.reset(seed=0, options={"designs": [0.45, 0.45, gcr, 0.01]})
    zs, ts = [], []
    for k in range(41):
        zs.append(robot_com(env)[0][2])
        ts.append(k * cfg.dt)
        env._physics_step()
    mass = robot_com(env)[1]
    env.close()
    acc = 2 * np.polyfit(ts, zs, 2)[0]
    assert -acc == pytest.approx((1 - gcr) * cfg.gravity, rel=0.015)
    assert mass == pytest.approx(ballu.mass_properties([0.45, 0.45, gcr, 0.01])["total"], rel=1e-6)


def test_ballu_drag_gives_the_terminal_velocity():
    """Falling far from the ground, 0.4 v^2 = (1 - gcr) M g sets the terminal speed (about 1.16 m/s)."""
    gcr = 0.72
    cfg = replace(BalluConfig(), start_z=30.0, drag_coef=ballu.HARDWARE_DRAG)   # the drag option
    env = BalluEnv(1, cfg)
    env.reset(seed=0, options={"designs": [0.45, 0.45, gcr, 0.01]})
    mass = ballu.mass_properties([0.45, 0.45, gcr, 0.01])["total"]
    for _ in range(800):                         # 4 s, about ten time constants
        env._physics_step()
    z0 = robot_com(env)[0][2]
    for _ in range(40):
        env._physics_step()
    v = (z0 - robot_com(env)[0][2]) / (40 * cfg.dt)
    env.close()
    assert v == pytest.approx(math.sqrt((1 - gcr) * mass * cfg.gravity / cfg.drag_coef), rel=0.03)
    f = ballu.balloon_force(0.8, 0.2, (1.0, -2.0, -0.5))
    assert f == pytest.approx([0.0, 0.0, 0.8 * 0.2 * 9.81])                  # no drag by default [facts]
    f = ballu.balloon_force(0.8, 0.2, (1.0, -2.0, -0.5), cfg)
    assert f == pytest.approx([-0.4, 1.6, 0.8 * 0.2 * 9.81 + 0.1])


def settle(designs, action, seconds=4.0):
    env = BalluEnv(len(designs))
    env.reset(seed=0, options={"designs": designs, "levels": 0})
    a = np.full((len(designs), 2), action)
    for _ in range(int(seconds / env.cfg.control_dt)):
        env.step(a)
    z = np.array([env.client(i).getBasePositionAndOrientation(b)[0][2] for i, b in enumerate(env.bodies)])
    env.close()
    return z


def test_ballu_standing_height_grows_with_leg_length():
    z = settle([[0.30, 0.30, 0.8, 0.01], [0.40, 0.40, 0.8, 0.01], [0.50, 0.50, 0.8, 0.01]], 0.0)
    # straight legs (zero action): pelvis near l_f + l_t + 0.068; each step adds 0.2 m of leg
    assert np.all(np.diff(z) > 0.15), z
    assert z[0] == pytest.approx(0.6 + 0.068, abs=0.08)


def test_ballu_larger_gcr_settles_higher_on_bent_knees():
    # With the tendon holding the knees bent (a = 0.5), more net weight bends them further:
    # measured 0.844 m (gcr 0.72) vs 0.890 m (gcr 0.90).
    z = settle([[0.45, 0.45, 0.72, 0.001], [0.45, 0.45, 0.90, 0.001]], 0.5)
    assert z[1] > z[0] + 0.02, z


def reference_knee_torque(q, qd, q_star, k):
    """Independent transcription of docs/facts.md's knee law (D term on the velocity clipped to +-7.48;
    spring preload 72.35 deg)."""
    spring = -2 * k * (q + 72.35 * math.pi / 180) - 0.001 * qd
    pd = max(0.0, 1.0 * (q_star - q) + 0.08 * float(np.clip(-qd, -7.48, 7.48)))
    return float(np.clip(spring + pd, -0.0848, 0.0848))


def test_ballu_knee_torque_matches_the_facts_formula():
    pts = [(0.0, 0.0, 0.0, 0.002), (0.5, 0.0, 0.6, 0.002), (0.5, 1.0, 0.6, 0.002), (1.2, -2.0, 0.3, 0.05),
           (0.2, 0.0, 1.7, 0.1), (1.7, 0.0, 0.0, 0.001), (0.3, -30.0, 0.9, 0.01), (1.0, 20.0, 1.7, 0.01)]
    for q, qd, qs, k in pts:
        assert ballu.knee_torque(q, qd, qs, k) == pytest.approx(reference_knee_torque(q, qd, qs, k), abs=1e-12)
    rng = np.random.default_rng(0)
    for q, qd, qs, k in zip(rng.uniform(0, 1.75, 500), rng.uniform(-30, 30, 500), rng.uniform(0, 1.75, 500),
                            rng.uniform(0.001, 0.1, 500)):
        tau = ballu.knee_torque(q, qd, qs, k)
        assert abs(tau) <= 0.0848 + 1e-12                                       # the clip holds
        spring = -2 * k * (q + 72.35 * math.pi / 180) - 0.001 * qd
        assert tau >= min(0.0848, max(-0.0848, spring)) - 1e-12                 # the tendon never pushes
        if qs - q - 0.08 * np.clip(qd, -7.48, 7.48) <= 0:
            assert tau == pytest.approx(min(0.0848, max(-0.0848, spring)))    # slack tendon: springs only


def test_ballu_servo_target_mapping():
    np.testing.assert_allclose(ballu.servo_target([-0.5, 0.25, 1.0, 2.0]), [0, math.pi / 4, math.pi, math.pi])


def rollout(env, actions, seed=0, options=None):
    obs, _ = env.reset(seed=seed, options=options)
    out = [obs]
    for a in actions:
        out.append(env.step(a)[0])
    return np.array(out)


def test_ballu_lanes_do_not_interact():
    """Lane 5 of 8 robots with other designs, the same robot alone, and in lane 0 of another world of 3
    follow bit-identical trajectories."""
    rng = np.random.default_rng(1)
    T = 80
    designs = np.column_stack([rng.uniform(0.25, 0.55, (8, 2)), rng.uniform(0.72, 0.9, 8), rng.uniform(0.001, 0.1, 8)])
    acts = rng.uniform(-0.2, 1.2, (T, 8, 2))
    batch = BalluEnv(8)
    tb = rollout(batch, acts, options={"designs": designs, "levels": 20})
    alone = BalluEnv(1)
    ta = rollout(alone, acts[:, 5:6], options={"designs": designs[5], "levels": 20})
    other = BalluEnv(3)
    to = rollout(other, acts[:, [5, 0, 1]], options={"designs": designs[[5, 0, 1]], "levels": 20})
    batch.close(), alone.close(), other.close()
    np.testing.assert_array_equal(tb[:, 5], ta[:, 0])
    np.testing.assert_array_equal(tb[:, 5], to[:, 0])
    assert np.abs(np.diff(tb[:, :, 0], axis=1)).max() > 1e-3   # the lanes did move differently


def test_ballu_same_design_scores_the_same_in_every_lane():
    # Six copies of one design under one gait: identical scores (no lane-dependent rounding).
    s = ballu.score(ballu.PumpGait(16), np.tile(D_MID, (6, 1)), "obstacle", episodes=2)
    assert np.all(s == s[0]), s


def d2_sampler(rng, n):
    """Uniform over D2 (module level, so worker processes can unpickle it)."""
    return np.column_stack([np.full((n, 2), 0.45), rng.uniform(0.72, 0.9, n), rng.uniform(0.001, 0.1, n)])


def test_ballu_same_seed_same_trajectory_and_workers_do_not_matter():
    sampler = d2_sampler
    cfg = replace(BalluConfig(), episode_steps=20)          # several auto-resets with sampled designs
    acts = np.random.default_rng(2).uniform(0, 1, (50, 4, 2))
    runs = []
    for _ in range(2):
        env = BalluEnv(4, cfg, design_sampler=sampler)
        runs.append(rollout(env, acts, seed=7))
        env.close()
    np.testing.assert_array_equal(runs[0], runs[1])
    env = ballu.VecBallu(4, 2, cfg, design_sampler=sampler)
    vec = rollout(env, acts, seed=7)
    env.close()
    np.testing.assert_array_equal(runs[0], vec)
    env = BalluEnv(4, cfg, design_sampler=sampler)
    other = rollout(env, acts, seed=8)
    env.close()
    assert not np.array_equal(runs[0], other)


@pytest.mark.parametrize("extra", [{}, {"tg": True, "random_first_episode": True}])
def test_ballu_get_state_then_set_state_in_a_fresh_env_goes_on_bit_for_bit(extra):
    """A state saved mid-episode (after auto-resets with new designs) and set into a fresh env, in one process
    or split over 2 workers, or back into the env it came from, gives the saved env's next 40 steps bit for
    bit (set_state replays each lane's episode so far); an env of other lanes refuses it by name."""
    cfg = replace(BalluConfig(task="obstacle"), episode_steps=40, **extra)
    acts = np.random.default_rng(3).uniform(0, 1, (130, 4, ballu.dims(cfg)[1]))
    env = BalluEnv(4, cfg, design_sampler=d2_sampler)
    env.reset(seed=5, options={"levels": 3})
    for a in acts[:90]:
        env.step(a)
    saved = env.get_state()
    ref = [env.step(a) for a in acts[90:]]
    for fresh in (BalluEnv(4, cfg, design_sampler=d2_sampler), ballu.VecBallu(4, 2, cfg, design_sampler=d2_sampler),
                  env):
        try:
            fresh.set_state(saved)
            for (o, r, te, tr, info), a in zip(ref, acts[90:]):
                o2, r2, te2, tr2, info2 = fresh.step(a)
                for x, y in ((o, o2), (r, r2), (te, te2), (tr, tr2), (info["levels"], info2["levels"])):
                    np.testing.assert_array_equal(x, y)
        finally:
            fresh.close()
    other = BalluEnv(3, cfg)
    with pytest.raises(ValueError, match=r"saved lanes \[0, 1, 2, 3\] do not match this env's lanes \[0, 1, 2\]"):
        other.set_state(saved)
    other.close()
    shared = BalluEnv(4, replace(cfg, lanes_per_world=2))
    assert shared.get_state() is None   # world-mates: no exact replay
    shared.close()


def test_ballu_design_hold_keeps_a_lane_on_its_design_for_that_many_episodes():
    """design_hold=3: a training lane draws a design at the full reset and then every 3rd episode, so its level
    can follow that design; the default 1 draws at every reset."""
    def designs_per_episode(hold):
        env = BalluEnv(2, replace(BalluConfig(), episode_steps=2, design_hold=hold), design_sampler=d2_sampler)
        env.reset(seed=3)
        seen = [env.designs.copy()]
        for _ in range(7):                       # 2 steps per episode: every 2nd step starts a new one
            for _ in range(2):
                env.step(np.full((2, 2), 0.5))
            seen.append(env.designs.copy())
        env.close()
        return np.array(seen)                    # (episodes, lanes, 4)
    one, three = designs_per_episode(1), designs_per_episode(3)
    changed = lambda d: [not np.array_equal(d[k], d[k - 1]) for k in range(1, len(d))]
    assert all(changed(one))
    assert changed(three) == [False, False, True, False, False, True, False]
    np.testing.assert_array_equal(three[0], one[0])          # the same first draw from the same lane seed


def test_ballu_random_first_episode_cuts_each_lanes_first_episode_at_its_own_step():
    """random_first_episode: a lane's first episode starts at a seeded random step of its episode_steps, so it
    ends after the rest of them, each lane at its own time; the next episodes are whole. score ignores it."""
    cfg = replace(BalluConfig(), episode_steps=12, random_first_episode=True)
    env = BalluEnv(3, cfg, design_sampler=d2_sampler)
    env.reset(seed=5)
    start = env.t.copy()
    assert len(set(start.tolist())) == 3 and start.min() >= 0 and start.max() < 12, start
    ends = []
    for k in range(1, 30):
        ends += [(int(i), k) for i in np.flatnonzero(env.step(np.full((3, 2), 0.5))[3])]
    env.close()
    for i in range(3):   # truncated after 12 - t0 steps, then after every further 12
        assert [k for lane, k in ends if lane == i] == [k for k in range(1, 30) if (k + start[i]) % 12 == 0], i
    env = BalluEnv(3, replace(cfg, random_first_episode=False), design_sampler=d2_sampler)
    env.reset(seed=5)
    assert not env.t.any()
    env.close()
    walk = lambda c: ballu.score(ballu.PumpGait(12), [BASELINE], episodes=1, cfg=c, final_x=True)[1]
    np.testing.assert_array_equal(walk(replace(BalluConfig(), random_first_episode=True)), walk(BalluConfig()))


def test_ballu_action_smoothing_applies_an_exponential_filter_that_the_observation_shows():
    """action_smoothing=beta: after k steps of action 1 (or 3, clipped to 1) from the start command a0, the
    applied command is 1 - beta^k (1 - a0), and it is what the observation's last-action entries hold."""
    beta = 0.6
    env = BalluEnv(2, replace(BalluConfig(), action_smoothing=beta))
    env.reset(seed=0, options={"designs": BASELINE, "levels": 0})
    a0 = env.last_action[0, 0]
    for k in range(1, 4):
        obs = env.step(np.array([[1.0, 1.0], [3.0, 1.0]]))[0]
        a_l = ballu.OBS_NAMES.index("a_l")
        np.testing.assert_allclose(obs[:, a_l:a_l + 2], 1 - beta ** k * (1 - a0), rtol=1e-6)
    env.close()


TG_OBS_NAMES = list(ballu.obs_names(BalluConfig(tg=True)))   # with BalluConfig.tg: its phase after a_l, a_r


@pytest.mark.parametrize("workers", [0, 2])
def test_ballu_trajectory_generator_pumps_both_knees_around_the_policys_centres(workers):
    """tg: actions (c_l, c_r, f, A) give knee commands c_k + 0.5 A sin(2 pi phase), clipped to [0, 1], the phase
    advancing (0.5 + 4.5 f) Hz x 0.05 s per step; the observation shows the commands and sin, cos of the phase,
    the design still last. In one process (0) and in worker processes (VecBallu)."""
    cfg = replace(BalluConfig(), tg=True)
    env = BalluEnv(2, cfg) if workers == 0 else ballu.make_env(2, workers, cfg)
    assert (env.obs_dim, env.act_dim) == (len(TG_OBS_NAMES), 4) == (ballu.OBS_DIM + 2, 4)
    env.reset(seed=0, options={"designs": BASELINE, "levels": 0})
    act = np.array([[0.5, 0.3, 0.2, 1.0], [0.9, 0.1, 1.0, 0.4]])
    names = list(TG_OBS_NAMES)
    a_l, s = names.index("a_l"), names.index("tg_sin")
    for k in range(1, 4):
        obs = env.step(act)[0]
        phase = k * (0.5 + 4.5 * act[:, 2]) * 0.05
        command = np.clip(act[:, :2] + 0.5 * act[:, 3:4] * np.sin(2 * np.pi * phase)[:, None], 0, 1)
        np.testing.assert_allclose(obs[:, a_l:a_l + 2], command, atol=1e-6)
        np.testing.assert_allclose(obs[:, s:s + 2], np.stack([np.sin(2 * np.pi * phase), np.cos(2 * np.pi * phase)], 1),
                                   atol=1e-6)
        np.testing.assert_allclose(obs[:, -4:], ballu.normalise_design(np.tile(BASELINE, (2, 1))), atol=1e-6)
    with pytest.raises(ValueError, match=r"actions must have shape \(2, 4\)"):
        env.step(np.zeros((2, 2)))
    env.close()


def test_ballu_curriculum_rule():
    assert list(ballu.curriculum_update("obstacle", [5, 5, 5, 74, 0], [1.01, 0.7, 0.49, 3.0, -1.0])) == [6, 5, 4, 74, 0]
    assert list(ballu.curriculum_update("ramp", [40, 40, 40], [1.71, 1.5, 1.29])) == [41, 40, 39]
    assert ballu.level_score("obstacle", 28) == pytest.approx(28.1)
    assert ballu.level_score("ramp", 40) == pytest.approx(math.degrees(math.atan(0.801 / 1.5)))
    # strict [ours]: only clearing keeps a level; it is the obstacle's rule, asked of the ramp it is an error
    assert list(ballu.curriculum_update("obstacle", [5, 5, 5, 0], [1.01, 0.7, 0.49, 0.7], strict=True)) == [6, 4, 4, 0]
    for task, strict in (("ramp", True), ("obstacle", "yes")):
        with pytest.raises(ValueError, match=r"strict=.*only for the obstacle"):
            ballu.curriculum_update(task, [5], [1.0], strict=strict)
    with pytest.raises(ValueError, match=r"strict=True for task='ramp'"):
        ballu.BalluEnv(1, ballu.BalluConfig(task="ramp", strict=True))
    assert ballu.episode_outcome("obstacle", [1.01, 0.7, 0.5, 0.49, np.nan]).tolist() == [2, 1, 1, 0, -1]
    assert ballu.episode_outcome("ramp", [1.71, 1.5, 1.29]).tolist() == [2, 1, 0]


def test_ballu_score_strict_moves_a_robot_in_the_band_down_each_episode(monkeypatch):
    """A robot that stands in the stay band keeps J's start level under the facts' rule; under the strict rule
    it goes down one level an episode. The band is moved to hold a standing robot (x ~ 0): the score's own path."""
    plain = ballu.task_geometry
    monkeypatch.setattr(ballu, "task_geometry", lambda task: {**plain(task), "down": -0.5})
    cfg = ballu.BalluConfig(obs="paper", episode_steps=10)
    j, x = ballu.score(ballu.stand, BASELINE[None], episodes=3, start_level=20, cfg=cfg, final_x=True)
    assert np.all(np.abs(x) < 0.5) and j[0] == pytest.approx(ballu.level_score("obstacle", 20))
    j = ballu.score(ballu.stand, BASELINE[None], episodes=3, start_level=20, cfg=cfg, strict=True)
    assert j[0] == pytest.approx(ballu.level_score("obstacle", 17))


@pytest.mark.slow
def test_ballu_stand_scores_low_and_curriculum_moves_down():
    # `stand` never reaches the obstacle: every episode ends with x < 0.5, 20 levels down from 28 (5 s episodes:
    # standing still needs no 20 s to show it, and they cost a quarter of the facts' episode)
    s = ballu.score(ballu.stand, [BASELINE, D_MID], "obstacle", cfg=replace(BalluConfig(), episode_steps=100))
    np.testing.assert_allclose(s, ballu.level_score("obstacle", 8))


def test_ballu_score_level_steps_of_ones_is_the_unit_step_J_and_steps_move_the_simulator():
    """level_steps=None and an all-ones schedule of length 20 give episodes=20's J and trajectories to the last
    bit; a schedule moves the real env by its steps (1 s episodes: every lane ends short of the box)."""
    cfg = replace(BalluConfig(), episode_steps=20)
    torch.manual_seed(5)
    policy = ppo.PolicyFn(ppo.make_policy("mlp", ballu.OBS_DIM, ballu.ACT_DIM, ppo.PPOConfig()),
                          ppo.RunningNorm(ballu.OBS_DIM))
    designs = [BASELINE, D_MID]
    ref, x_ref = ballu.score(policy, designs, "obstacle", episodes=20, start_level=30, cfg=cfg, final_x=True)
    assert np.unique(x_ref).size > 2                                   # the lanes and episodes did differ
    for kw in ({"level_steps": None}, {"level_steps": (1,) * 20, "episodes": 20}):
        j, x = ballu.score(policy, designs, "obstacle", start_level=30, cfg=cfg, final_x=True, **kw)
        np.testing.assert_array_equal(j, ref)
        np.testing.assert_array_equal(x, x_ref)
    j, x = ballu.score(policy, designs, "obstacle", start_level=30, cfg=cfg, final_x=True, level_steps=(16, 8, 4))
    assert x.shape == (2, 3) and (x < 0.5).all()
    np.testing.assert_allclose(j, ballu.level_score("obstacle", 30 - 16 - 8 - 4))


class ThresholdEnv:
    """Stands in for BalluEnv inside ballu.score: a policy whose success threshold is known. Each step is a
    whole episode; lane i's pelvis ends past `up` below level T[i], in the stay band at T[i] (if `stay`) and
    short of `down` above it. (No scripted BALLU gait has a clean threshold: a pump gait ends pressed against
    the box face, in the stay band, at some levels and short of it at others.)"""
    T, stay = np.array([0]), False

    def __init__(self, n, cfg, lane_ids=None, curriculum=True):
        self.task, self.level_step, self.T = cfg.task, 1, ThresholdEnv.T[lane_ids]

    def reset(self, seed=None, options=None):
        self.levels = np.asarray(options["levels"]).copy()
        return np.zeros((len(self.levels), ballu.OBS_DIM)), {}

    def step(self, actions):
        g, n = ballu.task_geometry(self.task), len(self.levels)
        at = (self.levels == self.T) & self.stay
        x = np.where(self.levels < self.T, g["up"] + 0.1, np.where(at, (g["up"] + g["down"]) / 2, g["down"] - 0.1))
        played = self.levels
        self.levels = ballu.curriculum_update(self.task, self.levels, x, self.level_step)   # as BalluEnv.step
        done = np.ones(n, dtype=bool)
        return np.zeros((n, ballu.OBS_DIM)), np.zeros(n), ~done, done, {
            "_final_obs": done, "final_x": x, "levels": self.levels.copy(), "episode_level": played,
            "blowup": ~done}

    def pause(self, lanes):
        pass

    def close(self):
        pass


@pytest.mark.parametrize("task", ballu.TASKS)
def test_ballu_score_bisection_lands_within_one_level_of_the_unit_walk(monkeypatch, task):
    """probe_agreement.BISECTION (7 episodes) ends within one level of the 20-episode J for every threshold the unit
    walk can reach (start +-19: not range-limited), with or without a stay band at the threshold."""
    start = ballu.SCORE_START_LEVEL[task]
    T = np.arange(start - 19, start + 20)
    monkeypatch.setattr(ballu, "BalluEnv", ThresholdEnv)
    monkeypatch.setattr(ThresholdEnv, "T", T)
    designs = np.tile(BASELINE, (len(T), 1))
    for stay in (False, True):
        monkeypatch.setattr(ThresholdEnv, "stay", stay)
        unit = [run_all.level_of(task, j) for j in ballu.score(ballu.stand, designs, task)]
        half = [run_all.level_of(task, j) for j in ballu.score(ballu.stand, designs, task,
                                                                level_steps=probe_agreement.BISECTION)]
        assert np.abs(np.subtract(unit, T)).max() <= 1 and np.abs(np.subtract(half, unit)).max() <= 1, (unit, half)
    short = [run_all.level_of(task, j) for j in ballu.score(ballu.stand, designs, task, level_steps=(8, 4, 2, 1))]
    assert np.abs(np.subtract(short, unit)).max() > 1      # a schedule reaching +-15 cannot follow every threshold


def test_ballu_score_level_steps_bad_input_raises_clear_errors():
    for bad in ((), (0,), (1, 75), (2.5,), "8421", (True,), [[1]], 3):
        with pytest.raises(ValueError, match=r"level_steps=.* must be None or a non-empty sequence of integers "
                                             r"in \[1, 74\]"):
            ballu.score(ballu.stand, BASELINE, level_steps=bad)
    with pytest.raises(ValueError, match=r"episodes=20 must be None or len\(level_steps\)=3"):
        ballu.score(ballu.stand, BASELINE, episodes=20, level_steps=(4, 2, 1))


def test_ballu_episode_limits_and_info():
    cfg = replace(BalluConfig(), episode_steps=5)
    env = BalluEnv(2, cfg)
    env.reset(seed=0, options={"levels": [3, 3]})
    for t in range(5):
        obs, r, term, trunc, info = env.step(np.zeros((2, 2)))
    assert trunc.all() and not term.any() and info["_final_obs"].all()
    assert obs.shape == (2, ballu.OBS_DIM) and np.isfinite(obs).all()
    assert list(info["levels"]) == [2, 2]                       # stood still: x < 0.5, one level down
    # A lane thrown past the height limit ends (terminated, flagged) while the other goes on.
    env.client(1).resetBasePositionAndOrientation(env.bodies[1], [0, 4.0, 6.0], [0, 0, 0, 1])
    obs, r, term, trunc, info = env.step(np.zeros((2, 2)))
    assert list(term) == [False, True] and info["blowup"][1] and not trunc.any()
    assert np.isfinite(obs).all() and np.isfinite(r).all()
    env.close()


def test_ballu_bad_input_raises_clear_errors():
    with pytest.raises(ValueError, match=r"lanes_per_world=0 must lie in \[1, 29\]"):
        BalluEnv(1, replace(BalluConfig(), lanes_per_world=0))
    with pytest.raises(ValueError, match="episodes=0 must be an integer >= 1"):
        ballu.score(ballu.stand, BASELINE, episodes=0)
    with pytest.raises(ValueError, match=r"start_level=80 must lie in \[0, 74\]"):
        ballu.score(ballu.stand, BASELINE, start_level=80)
    with pytest.raises(ValueError, match="gcr"):
        ballu.check_design([0.45, 0.45, 0.70, 0.002], ballu.TABLE_I_LOW, ballu.TABLE_I_HIGH)
    with pytest.raises(ValueError, match=r"l_f=2\.0 is outside"):
        ballu.check_design([2.0, 0.45, 0.8, 0.01])
    with pytest.raises(ValueError, match="spcf"):
        ballu.check_design([0.45, 0.45, 0.8, float("nan")])
    with pytest.raises(ValueError, match="shape"):
        ballu.check_design([0.45, 0.45, 0.8])
    env = BalluEnv(2)
    with pytest.raises(ValueError, match="options\\['designs'\\]: gcr"):
        env.reset(options={"designs": [0.45, 0.45, 1.5, 0.01]})
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros((2, 2)))
    env.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="non-finite"):
        env.step(np.array([[0.0, np.nan], [0.0, 0.0]]))
    with pytest.raises(ValueError, match="levels"):
        env.reset(options={"levels": 75})
    env.close()
    with pytest.raises(ValueError, match="task"):
        BalluEnv(1, replace(BalluConfig(), task="stairs"))


def test_ballu_dead_worker_gives_a_clear_error():
    env = ballu.VecBallu(2, 2)
    env.reset(seed=0)
    env.procs[1].kill()
    env.procs[1].join()
    with pytest.raises(RuntimeError, match="worker 1 died"):
        env.step(np.zeros((2, 2)))
    env.close()


def test_ballu_ramp_terrain_and_toe_height():
    # The ramp surface rises linearly; the obstacle top is flat; both are zero off the terrain.
    assert ballu.surface_height("ramp", np.array([0.4, 1.25, 2.0, 2.1]), 40).tolist() == pytest.approx(
        [0, 0.4005, 0.801, 0])
    assert ballu.surface_height("obstacle", np.array([0.4, 1.0, 1.6]), 30).tolist() == pytest.approx([0, 0.301, 0])
    cfg = replace(BalluConfig(), task="ramp", obs="paper")   # the paper form's task cue
    env = BalluEnv(1, cfg)
    obs, _ = env.reset(seed=0, options={"levels": 40})
    assert obs[0, ballu.obs_names(cfg).index("terrain_height")] == pytest.approx(0.801, abs=1e-6)
    env.close()


@pytest.mark.parametrize("task, level, top", [("obstacle", 30, 0.301), ("ramp", 40, 0.801)])
def test_ballu_terrain_spans_the_lane(task, level, top):
    """The terrain reaches 4 m to either side of the lane: no walking around it (a trained policy walked
    around a 2 m wide ramp). Its top is where the level says."""
    env = BalluEnv(1, replace(BalluConfig(), task=task))
    env.reset(seed=0, options={"levels": level})
    lo, hi = env.client(0).getAABB(env.terrain[0])
    env.close()
    assert lo[1] < -4.0 and hi[1] > 4.0
    assert hi[2] == pytest.approx(top, abs=0.02)      # AABBs carry a small collision margin


def test_ballu_base_frame_velocities_are_world_velocities_rotated_into_the_pelvis():
    """The observation's base velocities are R^T v (the base frame, as Isaac Lab reports them) [facts];
    checked against scipy's rotations and against the world-frame reading of a tilted, moving pelvis."""
    from scipy.spatial.transform import Rotation
    rng = np.random.default_rng(0)
    q = Rotation.random(50, random_state=1).as_quat()          # (x, y, z, w), as PyBullet
    v = rng.normal(size=(50, 3))
    np.testing.assert_allclose(ballu.to_base_frame(q, v), Rotation.from_quat(q).inv().apply(v), atol=1e-12)
    env = BalluEnv(1, replace(BalluConfig(), start_z=3.0))
    env.reset(seed=0)
    orn = pybullet.getQuaternionFromEuler([0.3, -0.6, 0.2])
    env.client(0).resetBasePositionAndOrientation(env.bodies[0], [0, 0, 3.0], orn)
    env.client(0).resetBaseVelocity(env.bodies[0], [0.7, 0.0, -0.2], [0.0, 1.5, 0.0])
    obs = env.observe()
    env.close()
    R = Rotation.from_quat(orn)
    np.testing.assert_allclose(obs[0, 0:3], R.inv().apply([0.7, 0.0, -0.2]), atol=1e-5)
    np.testing.assert_allclose(obs[0, 3:6], R.inv().apply([0.0, 1.5, 0.0]), atol=1e-5)
    assert abs(obs[0, 0] - 0.7) > 0.05                          # the frame really differs from the world's


def test_ballu_code_observation_reads_the_pelvis_and_each_knees_distance_to_the_box_edge():
    """obs="code" [facts]: a pelvis placed at (0.2, 0, 2.0) with the left hip at 0.4 rad puts the left knee
    l_f sin(0.4) behind the pelvis (a pitch rotation of the straight femur), the right one under it; the box's
    front edge is at x = 0.5, its height 1 cm per level. The form holds no base velocity; "code_vel" adds it."""
    cfg = BalluConfig(obs="code")
    env = BalluEnv(1, cfg)
    env.reset(seed=0, options={"levels": 10})
    p, b = env.client(0), env.bodies[0]
    p.resetBasePositionAndOrientation(b, [0.2, 0.0, 2.0], [0, 0, 0, 1])
    p.resetBaseVelocity(b, [0.3, 0.0, 0.0], [0.0, 0.5, 0.0])
    p.resetJointState(b, ballu.HIP_L, 0.4, 0.0)
    p.resetJointState(b, ballu.HIP_R, 0.0, 0.0)
    obs = dict(zip(ballu.obs_names(cfg), env.observe()[0]))
    env.close()
    l_f = 0.45
    assert obs["knee_l_to_edge"] == pytest.approx(0.5 - (0.2 - l_f * math.sin(0.4)), abs=1e-5)
    assert obs["knee_r_to_edge"] == pytest.approx(0.3, abs=1e-5)
    assert (obs["x"], obs["y"], obs["z"]) == pytest.approx((0.2, 0.0, 2.0), abs=1e-6)
    assert obs["dist_to_terrain"] == pytest.approx(0.3, abs=1e-6)
    assert obs["terrain_height"] == pytest.approx(0.101, abs=1e-6)
    assert not {"vx", "wy"} & set(obs) and list(obs)[-4:] == [f"design_{n}" for n in ballu.DESIGN_NAMES]
    assert ballu.obs_names(BalluConfig(obs="code_vel"))[:6] == ("vx", "vy", "vz", "wx", "wy", "wz")
    ramp = ballu.obs_names(BalluConfig(task="ramp", obs="code"))
    assert "vx" in ramp and "wx" not in ramp and "knee_l_to_edge" not in ramp
    assert ballu.obs_config(ballu.obs_names(BalluConfig(obs="code_vel", tg=True)), "obstacle") \
        == BalluConfig(obs="code_vel", tg=True) and ballu.obs_config(None).obs == "paper"


def _lanes(knees, axis=(0.0, 0.0, 1.0), pos=(0.0, 0.0, 1.0), vx=0.0):
    """A hand-made one-lane LaneState: knees (2, 3), both legs along `axis` (unit, foot to knee)."""
    knee = np.array([knees], dtype=float)
    leg_axis = np.broadcast_to(np.asarray(axis, dtype=float), (1, 2, 3)).copy()
    toe = knee - 0.45 * leg_axis
    return ballu.LaneState(np.array([pos], float), np.array([[vx, 0, 0, 0, 0, 0]], float), np.zeros((1, 5)),
                           np.zeros((1, 5)), toe, np.array([[0, 0, 0, 1.0]]), knee, leg_axis)


def test_ballu_code_reward_measures_at_the_feet_and_subtracts_the_box_only_under_both_feet():
    """reward_form="code" [facts], against hand-computed values (unscaled by dt): r_nav from the goal to the
    mean of the two tibia ends, 0.33 per m (obstacle) or 0.40 down to -2 (ramp); the jump term from the points
    3.4 cm below the tibia ends, the box height (level 10: 0.101 m) subtracted only when both are over it."""
    cfg = BalluConfig(reward_form="code", reward_dt_scale=False)
    l_t, h = np.array([0.4]), 0.101
    # tibia ends at x 1.0 and 1.2 (mean 1.1: d = 0.9), 0.2 m above the box; feet 3.4 cm lower
    s = _lanes([[1.0, 0.1, h + 0.6], [1.2, -0.1, h + 0.6]], vx=0.5)
    z = 0.2 - 0.034
    want = 5 * (1 - 0.33 * 0.9) + 3 * 0.5 + (math.exp(1.73 * z) - 1)
    assert ballu.reward("obstacle", cfg, s, np.array([10]), l_t)[0] == pytest.approx(want, rel=1e-9)
    # one foot short of the edge (x 0.45): the height is above the ground, box not subtracted
    s = _lanes([[0.45, 0.0, h + 0.6], [1.2, 0.0, h + 0.6]], vx=-0.5)
    d, z = 2.0 - (0.45 + 1.2) / 2, h + 0.2 - 0.034
    want = 5 * (1 - 0.33 * d) + 3 * (math.exp(-0.5) - 1) + (math.exp(1.73 * z) - 1)
    assert ballu.reward("obstacle", cfg, s, np.array([10]), l_t)[0] == pytest.approx(want, rel=1e-9)
    # far from the goal: r_nav floors at 0 (obstacle) and -2 (ramp); above 0.8 m/s r_vel is 0; above 1.8 m no jump
    far = _lanes([[-8.0, 0.0, 3.0], [-8.0, 0.0, 3.0]], vx=0.9)
    assert ballu.reward("obstacle", cfg, far, np.array([10]), l_t)[0] == 0.0
    assert ballu.reward("ramp", cfg, far, np.array([10]), l_t)[0] == pytest.approx(5 * -2.0)
    # the warm-up's nav scale multiplies r_nav alone
    half = ballu.reward("obstacle", cfg, _lanes([[1.5, 0, 0.5], [1.5, 0, 0.5]]), np.array([0]), l_t, 0.5)[0]
    assert half == pytest.approx(0.5 * 5 * (1 - 0.33 * 0.5) + (math.exp(1.73 * (0.1 - 0.034 - 0.001)) - 1))


def test_ballu_warmup_holds_the_curriculum_and_ramps_the_navigation_reward():
    """BalluConfig.warmup_steps [facts]: while the trainer's steps are < W a finished episode does not move its
    lane's level and r_nav is off; from W to 2 W r_nav is scaled by (steps - W) / W; an env never told the
    steps (as in score) has no warm-up."""
    W = 1000
    designs = np.tile(BASELINE, (2, 1))

    def run(warmup, told):
        env = BalluEnv(2, BalluConfig(reward_form="code", warmup_steps=warmup, episode_steps=3))
        env.reset(seed=0, options={"designs": designs, "levels": 5})
        if told is not None:
            env.schedule(told)
        p = env.client(0)
        p.resetBasePositionAndOrientation(env.bodies[0], [1.2, 0.0, 1.0], [0, 0, 0, 1])   # lane 0 past x = 1.0
        rewards, s = [], None
        for _ in range(3):
            s = env.read_lanes()
            rewards.append(env.step(np.full((2, 2), 0.3))[1])
        levels = env.levels.copy()
        env.close()
        return np.array(rewards), levels

    r_plain, lv_plain = run(0, None)
    assert lv_plain.tolist() == [6, 4]                                  # the curriculum moved both lanes
    assert run(W, None)[1].tolist() == [6, 4]                           # not told: no warm-up
    r_hold, lv_hold = run(W, 0)
    assert lv_hold.tolist() == [5, 5]                                   # held during the warm-up
    r_half = run(W, W + W // 2)[0]
    assert run(W, 2 * W)[1].tolist() == [6, 4]
    # the same trajectories (actions do not depend on the reward): r_nav = plain - held, half of it at 1.5 W
    np.testing.assert_allclose(r_half, r_hold + 0.5 * (r_plain - r_hold), rtol=1e-6, atol=1e-9)
    assert (r_plain - r_hold).min() > 0                                 # r_nav > 0 near the box


def test_ppo_a_checkpoint_of_one_observation_does_not_load_into_an_env_of_another(tmp_path):
    """The checkpoint keeps the env's observation names: resuming or warm-starting on an env that observes
    other entries of the same count is a clear error, and ballu.score refuses a policy that observed others (by
    name, or by count without names) and plays one on what it observed when not told otherwise."""
    env = PointMass(4)
    env.obs_names = ("x", "t")
    cfg = ppo.PPOConfig(num_envs=4, num_steps=8, minibatches=1, epochs=1)
    ckpt = str(tmp_path / "p.pt")
    ppo.train("mlp", env, None, 32, ckpt, cfg, progress=None)
    assert ppo.load_checkpoint(ckpt)["obs_names"] == ["x", "t"]
    env.obs_names = ("t", "x")
    with pytest.raises(ValueError, match=r"observed \['x', 't'\], this env observes \['t', 'x'\]"):
        ppo.train("mlp", env, None, 64, str(tmp_path / "q.pt"), cfg, init_ckpt=ckpt, progress=None)
    policy = ppo.load_policy(ckpt)
    policy.obs_names = ballu.obs_names(BalluConfig(obs="code"))
    with pytest.raises(ValueError, match="play it with the BalluConfig it trained with"):
        ballu.score(policy, BASELINE, "obstacle", cfg=BalluConfig())
    # without a cfg, a policy plays what it observed: its names, or the paper's form for a checkpoint without them
    assert ballu.policy_config(policy, "obstacle") == BalluConfig(obs="code")
    policy.obs_names = None
    with pytest.raises(ValueError, match=r"observed 2 entries \(names not kept\), this env \(obs='paper'"):
        ballu.score(policy, BASELINE, "obstacle")


def test_ballu_quirk_torque_rotates_with_the_balloon_and_rights_it():
    """r x F with r along the balloon's own axis: zero when upright, against the tilt when tilted [facts QUIRK];
    in the simulator a tilted balloon swings back faster with the quirk on."""
    lift = [0.0, 0.0, 1.5]
    upright = ballu.quirk_torque([0, 0, 0, 1], lift)
    assert np.allclose(upright, 0.0)
    for tilt in (0.3, -0.5):                                      # pitch about world y
        q = [0.0, math.sin(tilt / 2), 0.0, math.cos(tilt / 2)]
        tau = ballu.quirk_torque(q, lift)
        assert tau[1] == pytest.approx(-0.38 * math.sin(tilt) * 1.5) and np.sign(tau[1]) == -np.sign(tilt)
    swing = []
    for quirk in (False, True):
        cfg = replace(BalluConfig(), quirk_buoyancy_torque=quirk, start_z=3.0, drag_coef=0.0)
        env = BalluEnv(1, cfg)
        env.reset(seed=0, options={"designs": [0.45, 0.45, 0.9, 0.01]})
        env.client(0).resetJointState(env.bodies[0], ballu.NECK, 0.6, 0.0)   # balloon tilted 0.6 rad on its neck
        for _ in range(4):
            env.step(np.full((1, 2), 0.3))
        swing.append(env.client(0).getJointState(env.bodies[0], ballu.NECK)[0])
        env.close()
    assert swing[1] < swing[0] - 0.02, swing                      # the quirk turned it back further


ENERGY_TOL = 0.015   # J over an episode; see the test below


def test_ballu_random_open_loop_rollouts_are_stable_hold_joint_limits_and_create_no_energy():
    """Random piecewise-constant actions (bang-bang included) on random D3 designs and the baseline, with the
    default instant knee target: no blow-up, no joint more than 0.05 rad past its limit, and mechanical energy
    never rises by more than the work of the knee torques, buoyancy and drag + ENERGY_TOL.

    ENERGY_TOL = 15 mJ over a whole 8 s episode is 10 % of one full knee stroke's work (0.0848 N m x 1.75 rad
    = 0.148 J) and of lifting the robot's net weight by 0.3 m at gcr 0.72; measured rises are <= 6 mJ
    (`python -m experiments.ballu_capability --audit 200`)."""
    out = ballu_capability.stability_audit(episodes=16, steps=160, seed=3)
    assert not out["blowup"].any()
    assert out["limit_excess"].max() <= 0.05, out["limit_excess"].max()
    assert out["energy_rise"].max() <= ENERGY_TOL, out["energy_rise"].max()


def test_ballu_adaptive_substeps_switch_on_fast_or_near_limit_joints(monkeypatch):
    """needs_fine_substeps flags a joint faster than fine_speed or about to cross a limit within the step; the
    world then steps with substeps_fine. Forcing the rule on (off) gives fixed 8 (4) substeps' trajectory bit
    for bit, so the switch reaches Bullet; bang-bang knees trigger it in some steps, not in all."""
    dt, knee_max = BalluConfig().dt, math.radians(100)
    rest = [(0.0, 0.0)] * 3 + [(0.5, 0.0)] * 2                  # JOINTS order: neck, hips, knees
    assert not ballu.needs_fine_substeps(rest, dt, 15.0)
    assert ballu.needs_fine_substeps(rest[:3] + [(0.5, -15.5), (0.5, 0.0)], dt, 15.0)   # a fast knee
    assert ballu.needs_fine_substeps(rest[:4] + [(knee_max - 0.02, 5.0)], dt, 15.0)      # 0.025 rad past 100 deg
    assert not ballu.needs_fine_substeps(rest[:4] + [(knee_max - 0.03, 5.0)], dt, 15.0)  # stops 0.005 short
    assert ballu.needs_fine_substeps([(0.0, 0.0), (-math.pi / 2 + 0.01, -3.0)] + rest[2:], dt, 15.0)   # a hip
    acts = np.random.default_rng(5).integers(0, 2, (60, 2, 2)).astype(float)
    opts = {"designs": [[0.45, 0.45, 0.85, 0.05], [0.3, 0.3, 0.75, 0.002]], "levels": 10}

    def run(cfg):
        env = BalluEnv(2, cfg)
        out = rollout(env, acts, options=opts)
        env.close()
        return out, env.fine_steps / env.world_steps

    default, share = run(BalluConfig())
    assert 0 < share < 0.5, share
    monkeypatch.setattr(ballu, "needs_fine_substeps", lambda *a: True)
    np.testing.assert_array_equal(run(BalluConfig())[0], run(replace(BalluConfig(), substeps=8))[0])
    monkeypatch.setattr(ballu, "needs_fine_substeps", lambda *a: False)
    np.testing.assert_array_equal(run(BalluConfig())[0], run(replace(BalluConfig(), substeps_fine=4))[0])
    assert not np.array_equal(run(BalluConfig())[0], default)


@pytest.mark.parametrize("change, match", [({"substeps": 0}, r"substeps=0 must be an integer in \[1, 64\]"),
                                           ({"substeps_fine": 2}, "substeps_fine=2 must be >= substeps=4"),
                                           ({"drag_coef": -0.1}, "drag_coef=-0.1 must be a finite number >= 0"),
                                           ({"fine_speed": float("nan")}, "fine_speed=nan must be a finite"),
                                           ({"design_hold": 0}, r"design_hold=0 must be an integer in \[1, "),
                                           ({"action_smoothing": 1.0}, r"action_smoothing=1.0 must lie in \[0, 1\)"),
                                           ({"tg_freq": (2.0, 1.0)}, r"tg_freq=\(2.0, 1.0\) must be \(low, high\)"),
                                           ({"obs": "text"}, r"obs='text' is not one of \('paper', 'code'"),
                                           ({"reward_form": "x"}, r"reward_form='x' is not one of"),
                                           ({"warmup_steps": -1}, "warmup_steps=-1 must be an integer >= 0")])
def test_ballu_bad_simulator_settings_name_the_field(change, match):
    with pytest.raises(ValueError, match=match):
        BalluEnv(1, replace(BalluConfig(), **change))


def test_ballu_energy_audit_accounts_for_the_work_done_in_free_flight():
    """The energy audit of the test above must be accurate: in free flight, away from every limit and contact,
    the balance stays within 1 % of the work done (measured 0.3 %, halving with the time step: the integrator's
    own error), both ways, so a missing or wrong work term shows."""
    cfg = replace(BalluConfig(), start_z=3.0, episode_steps=1000)
    env = BalluEnv(2, cfg, curriculum=False)
    env.reset(seed=0, options={"designs": [[0.45, 0.45, 0.9, 0.05], [0.3, 0.3, 0.85, 0.01]]})
    mon = env.monitor = ballu_capability.EnergyAudit(env)
    trace = []
    for a in np.random.default_rng(0).uniform(0.25, 0.75, (20, 2, 2)):
        env.step(a)
        trace.append(mon.balance.copy())
    z = env.read_lanes().pos[:, 2]
    env.close()
    assert (z > 1.9).all()                                          # still in the air
    assert (mon.work > 0.5).all()                                   # much work was done (0.7-0.9 J) ...
    assert (np.abs(trace).max(axis=0) < 0.01 * mon.work).all(), np.abs(trace).max()   # ... and accounted for


def test_experiments_capability_gaits_and_clearance_measure():
    """The capability search's gait family holds the pump gaits exactly, and a standing robot's peak toe
    clearance is ~0: the spawn drop (feet 0.2-0.3 m up at t = 0) does not count as a jump."""
    acts = ballu_capability.gait_actions(ballu_capability.PUMP_GAITS, 60)
    for k, (period, mode) in enumerate([(p, m) for m in ("sync", "alternate") for p in range(4, 41, 4)]):
        pump = ballu.PumpGait(period, mode)
        np.testing.assert_array_equal(acts[k], [pump(np.zeros((1, 1)))[0] for _ in range(60)])
    out = ballu_capability.play_open_loop(BASELINE, np.zeros((1, 40, 2)))
    assert out["peak_clearance"][0] < 0.02 and not out["blowup"][0]



def test_experiments_stay_band_variants_edit_only_what_they_name():
    """The stay-band study's robot variants: the older legs keep 2 colliders per tibia (the tibia's 13-65 %, the
    foot at its tip), the balloon variant drops its collider only, and both restore ballu.robot_urdf after use."""
    import xml.etree.ElementTree as ET
    from experiments import stay_band
    plain = ballu.robot_urdf
    with stay_band.variant("older_legs", ballu.BalluConfig()) as cfg:
        root = ET.fromstring(ballu.robot_urdf(BASELINE, cfg))
    assert ballu.robot_urdf is plain and cfg == ballu.BalluConfig()
    tibia = next(link for link in root.iter("link") if link.get("name") == "tibia_l")
    cols = tibia.findall("collision")
    assert len(cols) == 2 and float(cols[1].find("origin").get("xyz").split()[2]) == pytest.approx(-0.45)
    assert float(cols[0].find("geometry/cylinder").get("length")) == pytest.approx(0.20 / 0.385 * 0.45, abs=1e-6)
    with stay_band.variant("drag", ballu.BalluConfig()) as cfg:
        assert cfg.drag_coef == ballu.HARDWARE_DRAG and ballu.robot_urdf is plain
    with stay_band.variant("no_balloon_contact", ballu.BalluConfig()):
        root = ET.fromstring(ballu.robot_urdf(BASELINE))
    links = {link.get("name"): link for link in root.iter("link")}
    assert not links["balloon"].findall("collision") and len(links["tibia_r"].findall("collision")) == 3

# --- design spaces (paper Table I; the authors' experiments' boxes and D2 robots [facts]) ---
D2_BOX = ges.Box(("gcr", "spcf"), (0.72, 0.001), (0.90, 0.100))             # D2's Table I bounds as a plain box
D3_BOX = ges.Box(("gcr", "spcf", "l"), (0.72, 0.001, 0.25), (0.90, 0.100, 0.55))


def test_ballu_table_i_baseline_and_box():
    assert ballu.TABLE_I == {"l_f": (0.25, 0.55), "l_t": (0.25, 0.55), "gcr": (0.72, 0.90), "spcf": (0.001, 0.100)}
    assert dict(zip(ballu.DESIGN_NAMES, BASELINE)) == {"l_f": 0.45, "l_t": 0.45, "gcr": 0.70, "spcf": 0.002}
    with pytest.raises(ValueError, match="gcr"):  # the baseline's GCR lies outside Table I (facts)
        ballu.d2().validate([BASELINE[2], BASELINE[3]])
    assert ges.Box.of(ballu.d2()) == D2_BOX and ges.Box.of(ballu.d3()) == D3_BOX


def test_ballu_d2_d3_bounds_and_full():
    s2, s3 = ballu.d2(), ballu.d3()
    assert s2.names == ("gcr", "spcf") and s2.lows == (0.72, 0.001) and s2.highs == (0.90, 0.100)
    assert s3.names == ("gcr", "spcf", "l") and s3.lows == (0.72, 0.001, 0.25) and s3.highs == (0.90, 0.1, 0.55)
    np.testing.assert_allclose(s2.full([0.8, 0.05]), [[0.45, 0.45, 0.8, 0.05]])
    np.testing.assert_allclose(s3.full([[0.8, 0.05, 0.3], [0.9, 0.1, 0.55]]),
                               [[0.3, 0.3, 0.8, 0.05], [0.55, 0.55, 0.9, 0.1]])
    assert ballu.d2("ramp").lows == s2.lows and ballu.d2("ramp").setup == "table"  # a task alone: Table I


def test_ballu_authors_setup_boxes_and_d2_robots():
    """setup='authors': each task's box and D2 robot as the authors' GES configurations have them (docs/facts.md
    sec. 14, their scripts/pec/configs at 104e07b): numbers typed from the facts, not from ballu's tables."""
    ob, ramp = ballu.d2("obstacle", "authors"), ballu.d2("ramp", "authors")
    ob3, ramp3 = ballu.d3("obstacle", "authors"), ballu.d3("ramp", "authors")
    assert ob.lows == (0.75, 0.001) and ob.highs == (0.89, 0.010)
    assert ramp.lows == (0.725, 0.005) and ramp.highs == (0.89, 0.100)
    assert ob3.lows == (0.75, 0.001, 0.20) and ob3.highs == (0.89, 0.010, 0.48)
    assert ramp3.lows == (0.725, 0.005, 0.20) and ramp3.highs == (0.89, 0.100, 0.48)
    np.testing.assert_allclose(ob.full([0.8, 0.005]), [[0.480, 0.443, 0.8, 0.005]])   # unequal legs
    np.testing.assert_allclose(ramp.full([0.8, 0.05]), [[0.286, 0.215, 0.8, 0.05]])
    np.testing.assert_allclose(ob3.full([0.8, 0.005, 0.3]), [[0.3, 0.3, 0.8, 0.005]])
    assert ob.to_dict()["setup"] == "authors" and "authors" in ob.label and "obstacle D2" in ob.label
    preset = replace(run_all.SMOKE, setup="authors")
    for t, sp, space in (("obstacle", "d2", ob), ("ramp", "d2", ramp), ("ramp", "d3", ramp3)):
        assert policies.space_of(preset, t, sp) == space   # every stage's one funnel
    theta = ob.sample_uniform(np.random.default_rng(0), 200)   # test designs: inside the authors' box
    assert (theta[:, 1] <= 0.010).all() and (theta[:, 0] >= 0.75).all()


def test_box_contains_agrees_with_validate():
    """contains answers, row by row, what validate would raise on: edges and round-off in, NaN and beyond out."""
    box = ballu.d2("obstacle", "authors")
    rows = [[0.75, 0.001], [0.89, 0.010 + 1e-13], [0.80, 0.05], [0.70, 0.005], [np.nan, 0.005], [0.8, 0.0099]]
    want = []
    for r in rows:
        try:
            box.validate(r)
            want.append(True)
        except ValueError:
            want.append(False)
    assert want == [True, True, False, False, False, True]
    assert box.contains(rows).tolist() == want and box.contains(rows[0]).tolist() == [True]
    with pytest.raises(ValueError, match="expected"):   # a wrong width is an error, not silently reshaped
        box.contains([0.8, 0.005, 0.8, 0.005])


def test_use_design_outside_the_authors_box_names_it():
    """A design outside the active box is a one-line error naming the box; D2's legs are the task's robot's."""
    ob = ballu.d2("obstacle", "authors")
    with pytest.raises(use.UseError) as e:
        use.design_arg("gcr=0.8,spcf=0.05", ob)   # inside Table I's box, outside the authors' obstacle box
    msg = str(e.value)
    assert "\n" not in msg and "spcf=0.05" in msg and "the authors' box" in msg and "[0.001, 0.01]" in msg, msg
    with pytest.raises(use.UseError, match="l_f is not free.*0.48"):
        use.design_arg("gcr=0.8,spcf=0.005,l_f=0.45", ob)
    assert use.design_arg("gcr=0.8,spcf=0.005,l_f=0.48", ob).full.tolist() == [0.48, 0.443, 0.8, 0.005]
    assert use.design_arg("baseline", ob).full.tolist() == ballu.BASELINE.tolist()   # the paper's robot, as ever


def test_run_all_refuses_to_resume_in_another_setup(tmp_path, capsys):
    """A run folder made in one setup refuses to go on in the other (the manifest's budgets), writing nothing."""
    out = str(tmp_path / "run")
    base = ["--preset", "smoke", "--out", out, "--workers", "1", "--only", "table1"]
    assert run_all.main(base + ["--set", "setup=authors"]) == 0
    before = open(os.path.join(out, "manifest.json")).read()
    capsys.readouterr()
    assert run_all.main(base) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "setup ('authors' there, 'table' now)" in err, err
    assert open(os.path.join(out, "manifest.json")).read() == before


# ==========================================================================================================
# ppo.py: GAE against brute force, a toy env solved, checkpoints, MoE gate
# ==========================================================================================================


def brute_force_returns(rewards, values, dones, last_value, gamma, lam):
    """lambda-returns by their definition: a weighted sum of n-step returns, cut at episode ends."""
    T, N = rewards.shape
    adv = np.zeros((T, N))
    for n in range(N):
        for t in range(T):
            total, weight = 0.0, 1.0
            for k in range(t, T):
                nextv = last_value[n] if k == T - 1 else values[k + 1, n]
                delta = rewards[k, n] + gamma * nextv * (1 - dones[k, n]) - values[k, n]
                total += weight * delta
                if dones[k, n]:
                    break
                weight *= gamma * lam
            adv[t, n] = total
    return adv


def test_ppo_gae_equals_brute_force_with_terminations_and_truncations():
    rng = np.random.default_rng(0)
    T, N = 30, 5
    r, v = rng.normal(size=(T, N)), rng.normal(size=(T, N))
    dones = (rng.uniform(size=(T, N)) < 0.15).astype(float)   # truncations carry their bootstrap in r
    last = rng.normal(size=N)
    adv, ret = ppo.gae(r, v, dones, last, 0.99, 0.95)
    np.testing.assert_allclose(adv, brute_force_returns(r, v, dones, last, 0.99, 0.95), atol=1e-10)
    np.testing.assert_allclose(ret, adv + v)
    # lambda = 1 without episode ends: the plain discounted return bootstrapped at the end
    adv1, ret1 = ppo.gae(r, v, np.zeros((T, N)), last, 0.9, 1.0)
    disc = [sum(0.9 ** (k - t) * r[k] for k in range(t, T)) + 0.9 ** (T - t) * last for t in range(T)]
    np.testing.assert_allclose(ret1, np.array(disc), atol=1e-10)


class PointMass:
    """A batched toy env: a point on a line driven to the origin; reward -|x|; 40-step episodes."""

    def __init__(self, num_envs=16):
        self.num_envs, self.obs_dim, self.act_dim = num_envs, 2, 1

    def reset(self, seed=None, options=None):
        self.rng = np.random.default_rng(seed)
        self.x, self.t = self.rng.uniform(-1, 1, self.num_envs), np.zeros(self.num_envs, int)
        self.ret = np.zeros(self.num_envs)
        return self._obs(), {"levels": np.zeros(self.num_envs)}

    def _obs(self):
        return np.stack([self.x, self.t / 40.0], 1).astype(np.float32)

    def step(self, a):
        self.x = np.clip(self.x + 0.1 * np.clip(a[:, 0], -1, 1), -2, 2)
        self.t += 1
        r = -np.abs(self.x)
        self.ret += r
        trunc = self.t >= 40
        obs = self._obs()
        info = {"final_obs": obs.copy(), "_final_obs": trunc, "episode_return": np.where(trunc, self.ret, np.nan),
                "levels": np.zeros(self.num_envs)}
        if trunc.any():
            self.x[trunc] = self.rng.uniform(-1, 1, trunc.sum())
            self.t[trunc], self.ret[trunc] = 0, 0
            obs = self._obs()
        return obs, r.astype(np.float32), np.zeros(self.num_envs, bool), trunc, info


def point_mass_return(policy_fn, episodes=64):
    env = PointMass(episodes)
    obs, _ = env.reset(seed=99)
    total = np.zeros(episodes)
    for _ in range(40):
        obs, r, *_ = env.step(policy_fn(obs))
        total += r
    return total.mean()


def test_ppo_solves_a_point_mass(tmp_path):
    """Random start |x| ~ U(0,1): a do-nothing policy scores about -20 per episode, the optimum about -2.8."""
    cfg = ppo.PPOConfig(num_envs=16, num_steps=40, lr=3e-4)
    ck = str(tmp_path / "pm.pt")
    ppo.train("mlp", PointMass(16), None, 40_000, ck, cfg, seed=0, progress=None,
              log_csv=str(tmp_path / "pm.csv"))
    pf = ppo.load_policy(ck)
    zero = point_mass_return(lambda o: np.zeros((len(o), 1)))
    learned = point_mass_return(pf)
    assert zero < -15 and learned > -6, (zero, learned)
    assert os.path.exists(ppo.plot_learning_curve(str(tmp_path / "pm.csv"), str(tmp_path / "pm.png")))


class PointMassLevels(PointMass):
    """The point mass with a curriculum level that a schedule sets after the u-th update of 40 steps: -(u - 14)^2,
    but 5 at u = 12 (one lucky update); u counts from `first_update` (a resumed run's env goes on where the
    stopped one ended)."""

    def __init__(self, num_envs=16, first_update=0):
        super().__init__(num_envs)
        self.calls = first_update * 40

    def step(self, a):
        out = super().step(a)
        self.calls += 1
        out[-1]["levels"] = np.full(self.num_envs, self.level(math.ceil(self.calls / 40)))
        return out

    def level(self, u):
        return 5.0 if u == 12 else -float((u - 14) ** 2)


class PointMassFalls(PointMassLevels):
    """Levels |u - 12|: high at the start (lanes started spread up to the score's level), down to 0 at update
    12 while the policy learns, back up to 6 at update 18, never above the first updates' 11."""

    def level(self, u):
        return float(abs(u - 12))


def test_ppo_keeps_the_policy_of_the_best_level_and_a_resumed_run_carries_it(tmp_path):
    """Checkpoints every 3 updates; the best 3-update mean level is that of updates 13-15 (-2/3, against -20/3
    for 10-12 with its lucky 5, and -29/3 for 16-18): the best policy is the checkpoint at update 15, 15 x 640
    steps, neither the last (30) nor the lucky update's (12). A run stopped at update 18 and resumed keeps that
    best file untouched: the resumed windows (-110/3 and lower) do not beat the best level it carries."""
    cfg = ppo.PPOConfig(num_envs=16, num_steps=40, lr=3e-4, ckpt_every=3)
    ck, ck2 = str(tmp_path / "a.pt"), str(tmp_path / "b.pt")
    out = ppo.train("mlp", PointMassLevels(16), None, 30 * cfg.batch, ck, cfg, seed=0, progress=None)
    assert out["resumed"] is False
    best = ppo.load_checkpoint(ppo.best_path(ck))
    assert (out["best_steps"], best["steps"]) == (15 * cfg.batch, 15 * cfg.batch), out
    assert out["best_level"] == pytest.approx(-2 / 3) and best["extra"]["best"]["level"] == pytest.approx(-2 / 3)
    assert ppo.load_checkpoint(ck)["steps"] == 30 * cfg.batch
    ppo.train("mlp", PointMassLevels(16), None, 18 * cfg.batch, ck2, cfg, seed=0, progress=None)
    first = ppo.load_checkpoint(ppo.best_path(ck2))
    out = ppo.train("mlp", PointMassLevels(16, first_update=18), None, 30 * cfg.batch, ck2, cfg, seed=0,
                    progress=None)
    again = ppo.load_checkpoint(ppo.best_path(ck2))
    assert out["resumed"] is True
    assert first["steps"] == again["steps"] == out["best_steps"] == 15 * cfg.batch
    for k, w in first["policy"].items():
        assert torch.equal(w, again["policy"][k]), k
    assert ppo.scored_path(ck) == ppo.best_path(ck) and ppo.scored_path(ck, "last") == ck
    assert ppo.scored_path(str(tmp_path / "none.pt")) == str(tmp_path / "none.pt")   # trained before: the last
    with pytest.raises(ValueError, match="rule='top' must be 'best' or 'last'"):
        ppo.scored_path(ck, "top")


def test_ppo_best_policy_comes_after_the_lowest_level_while_the_first_is_unbeaten(tmp_path):
    """3-update windows of |u - 12|: 10, 7, 4, 1, 2, 5 at updates 3-18. No window beats the first (10), so the
    high start is not skill: the best is the last window past the lowest (update 18, level 5), not the first
    (the plain rule's, update 3). A run stopped at update 6 (best: 7 there) and resumed carries the first
    window's level: a record without it would keep update 6 (no later window beats 7). (The point mass keeps no
    lane state: the resumed run's policy is another one, its best's steps the same.)"""
    cfg = ppo.PPOConfig(num_envs=16, num_steps=40, lr=3e-4, ckpt_every=3)
    ck, ck2 = str(tmp_path / "a.pt"), str(tmp_path / "b.pt")
    out = ppo.train("mlp", PointMassFalls(16), None, 18 * cfg.batch, ck, cfg, seed=0, progress=None)
    assert (out["best_steps"], out["best_level"]) == (18 * cfg.batch, 5.0), out
    assert ppo.load_checkpoint(ppo.best_path(ck))["extra"]["best"] == {"level": 5.0, "steps": 18 * cfg.batch,
                                                                       "first": 10.0, "low": 1.0}
    ppo.train("mlp", PointMassFalls(16), None, 6 * cfg.batch, ck2, cfg, seed=0, progress=None)
    assert ppo.load_checkpoint(ppo.best_path(ck2))["steps"] == 6 * cfg.batch
    out = ppo.train("mlp", PointMassFalls(16, first_update=6), None, 18 * cfg.batch, ck2, cfg, seed=0,
                    progress=None)
    assert out["resumed"] is True and out["best_steps"] == 18 * cfg.batch, out
    assert ppo.load_checkpoint(ppo.best_path(ck2))["extra"]["best"]["first"] == 10.0
    # the rule itself: a level that beats the first window ends the resets; an older record has no first
    beaten = {"level": 12.0, "steps": 9, "first": 10.0, "low": 4.0}
    assert ppo.next_best(beaten, 3.0, 12) is None and ppo.next_best(beaten, 13.0, 12)["steps"] == 12
    assert ppo.next_best({"level": 7.0, "steps": 6}, 1.0, 12) is None


@pytest.mark.parametrize("episode_steps,lane_t", [(40, 16), (32, 0)])
def test_ppo_killed_on_ballu_and_rerun_equals_uninterrupted(tmp_path, episode_steps, lane_t):
    """A BALLU training killed mid-way (here after update 7; checkpoints every 2) and rerun goes on from the
    lanes' saved state: its final and best checkpoints equal an uninterrupted run's bit for bit. The
    unfinished checkpoint holds that state, the finished ones none. With 40-step episodes the kill lands mid-way
    in episode 3; with 32 the checkpoint lands just as every lane's episode begins (no actions yet): such a
    checkpoint read as damaged until 2026-11-28, and its run started over."""
    cfg = ppo.PPOConfig(num_envs=4, num_steps=16, ckpt_every=2)
    bcfg = replace(BalluConfig(task="obstacle"), episode_steps=episode_steps)
    sampler, total = ballu.UniformDesign(ballu.d2("obstacle")), 12 * 64

    class Kill(Exception):
        pass

    def kill_after(n):
        lines = []

        def progress(line):
            lines.append(line)
            if len(lines) == n:
                raise Kill
        return progress

    def train(ck, progress=None):
        env = BalluEnv(4, bcfg)
        try:
            return ppo.train("mlp", env, sampler, total, ck, cfg, seed=3, start_level=(0, 6), progress=progress)
        finally:
            env.close()

    a, b = str(tmp_path / "a.pt"), str(tmp_path / "b.pt")
    train(a)
    with pytest.raises(Kill):
        train(b, kill_after(7))
    mid = ppo.load_checkpoint(b)
    assert mid["steps"] == 6 * 64 and [lane["t"] for lane in mid["run"]["env"]] == [lane_t] * 4
    assert train(b)["resumed"] is True
    for x, y in ((a, b), (ppo.best_path(a), ppo.best_path(b))):
        sx, sy = ppo.load_checkpoint(x), ppo.load_checkpoint(y)
        assert "run" not in sx and "run" not in sy and sx["steps"] == sy["steps"]
        for k in sx["policy"]:
            assert torch.equal(sx["policy"][k], sy["policy"][k]), (x, k)
        assert sx["norm"]["mean"].tolist() == sy["norm"]["mean"].tolist()


def test_ppo_adaptive_kl_rate_is_clamped_at_max_lr(tmp_path):
    """PPOConfig.max_lr caps the adaptive-KL rate (ours 1e-3, the facts 1e-2): on the point mass the KL
    stays small, so the rate grows x1.5 per minibatch until it meets the cap, and never passes it."""
    cfg = ppo.PPOConfig(num_envs=16, num_steps=40, lr=1e-4, max_lr=2e-4)
    log = str(tmp_path / "pm.csv")
    ppo.train("mlp", PointMass(16), None, 6 * cfg.batch, str(tmp_path / "pm.pt"), cfg, seed=0, progress=None,
              log_csv=log)
    with open(log) as fh:
        lrs = [float(row["lr"]) for row in csv_module.DictReader(fh)]
    assert max(lrs) == pytest.approx(2e-4) and all(lr <= 2e-4 * (1 + 1e-9) for lr in lrs), lrs


def test_ppo_scale_rewards_divides_by_the_std_of_each_lanes_discounted_return():
    """reward_norm: rewards / std of every lane's discounted return so far (brute force over two rollouts,
    episodes cut by dones, the running statistics carried across); the time-limit bootstrap is added unscaled.
    Off: the rewards plus the bootstrap, unchanged."""
    rng = np.random.default_rng(1)
    T, N, gamma = 25, 4, 0.9
    cfg = ppo.PPOConfig(gamma=gamma, reward_norm=True)
    bufs = [{"rew": rng.normal(-3, 2, (T, N)).astype(np.float32), "done": (rng.uniform(size=(T, N)) < 0.1)
             .astype(np.float32), "boot": rng.normal(size=(T, N)).astype(np.float32)} for _ in range(2)]
    seen, ends = np.concatenate([b["rew"] for b in bufs]), np.concatenate([b["done"] for b in bufs])
    acc, ret_norm = np.zeros(N, np.float32), ppo.RunningNorm(1)
    for i, b in enumerate(bufs):
        out = ppo.scale_rewards(b, acc, ret_norm, cfg)
        disc = []   # brute force over every step so far: R_t = sum over k <= t in t's episode of gamma^(t-k) r_k
        for n in range(N):
            start = 0
            for t in range(T * (i + 1)):
                disc.append(sum(gamma ** (t - k) * seen[k, n] for k in range(start, t + 1)))
                start = t + 1 if ends[t, n] else start
        np.testing.assert_allclose(out, b["rew"] / np.std(disc) + b["boot"], rtol=1e-4, atol=1e-6)
    off = ppo.scale_rewards(bufs[0], np.zeros(N, np.float32), ppo.RunningNorm(1), ppo.PPOConfig())
    np.testing.assert_array_equal(off, bufs[0]["rew"] + bufs[0]["boot"])


def test_ppo_reward_norm_solves_the_point_mass_and_resumes_its_statistics(tmp_path):
    """The point mass of the test above with reward_norm: learned, and the return statistics are in the
    checkpoint; a resumed run starts from them."""
    cfg = ppo.PPOConfig(num_envs=16, num_steps=40, lr=3e-4, reward_norm=True)
    ck = str(tmp_path / "pm.pt")
    ppo.train("mlp", PointMass(16), None, 40_000, ck, cfg, seed=0, progress=None)
    learned = point_mass_return(ppo.load_policy(ck))
    state = ppo.load_checkpoint(ck)
    assert learned > -6 and state["ret_norm"]["count"] > 30_000, (learned, state["ret_norm"])
    start = ppo.start_run("mlp", PointMass(16), ck, None, cfg, 0, 0)
    assert float(start.ret_norm.var[0]) == float(state["ret_norm"]["var"][0]) > 1.5


@pytest.mark.parametrize("kind", ["mlp", "moe"])
def test_ppo_max_std_bounds_the_action_std_that_the_entropy_bonus_widens(kind, tmp_path):
    """A large entropy bonus widens the std past 0.5 within a few updates; PPOConfig.max_std = 0.3 holds it
    at 0.3 (a projection after every optimiser step), for both actor-critics."""
    stds = {}
    for max_std in (0.0, 0.3):
        cfg = ppo.PPOConfig(num_envs=8, num_steps=16, entropy_coef=1.0, lr=1e-2, max_std=max_std, design_dim=1)
        ck = str(tmp_path / f"{kind}{max_std}.pt")
        ppo.train(kind, PointMass(8), None, 8 * 16 * 8, ck, cfg, seed=0, progress=None)
        stds[max_std] = ppo.load_checkpoint(ck)["policy"]["log_std"].exp().max().item()
    assert stds[0.0] > 0.5 and stds[0.3] <= 0.3 + 1e-6, stds


def test_ppo_checkpoint_round_trip_and_clear_errors(tmp_path):
    cfg = ppo.PPOConfig(num_envs=8, num_steps=8, design_dim=1)   # the MoE gate reads the last obs entry
    ck = str(tmp_path / "a.pt")
    ppo.train("moe", PointMass(8), None, 64, ck, cfg, seed=1, progress=None)
    obs = np.random.default_rng(0).normal(size=(5, 2)).astype(np.float32)
    a1, a2 = ppo.load_policy(ck)(obs), ppo.load_policy(ck)(obs)
    np.testing.assert_array_equal(a1, a2)
    state = ppo.load_checkpoint(ck)
    policy, norm = ppo.policy_from(state)
    with torch.no_grad():
        direct = policy.mean(torch.from_numpy(norm(obs))).numpy()
    np.testing.assert_allclose(a1, direct, rtol=1e-6)
    # resuming the finished run does nothing; more steps continue from its step count
    assert ppo.train("moe", PointMass(8), None, 64, ck, cfg, progress=None)["resumed"]
    assert ppo.train("moe", PointMass(8), None, 128, ck, cfg, progress=None)["steps"] == 128
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="truncated, damaged or not a ppo.py checkpoint"):
        ppo.load_checkpoint(str(bad))
    with pytest.raises(FileNotFoundError):
        ppo.load_checkpoint(str(tmp_path / "missing.pt"))
    with pytest.raises(ValueError, match="not a mlp policy"):
        ppo.train("mlp", PointMass(8), None, 64, str(tmp_path / "b.pt"), cfg, init_ckpt=ck, progress=None)


def test_ppo_train_start_level_is_one_level_or_a_uniform_spread(tmp_path):
    """start_level=(low, high) starts each lane at its own level in [low, high]; an int starts all at it."""
    seen = []

    class Recording(PointMass):
        def reset(self, seed=None, options=None):
            seen.append(np.asarray(options["levels"]).copy())
            return super().reset(seed=seed, options=options)

    cfg = ppo.PPOConfig(num_envs=64, num_steps=4)
    ppo.train("mlp", Recording(64), None, 256, str(tmp_path / "a.pt"), cfg, start_level=(3, 9), progress=None)
    ppo.train("mlp", Recording(64), None, 256, str(tmp_path / "b.pt"), cfg, start_level=5, progress=None)
    assert seen[0].min() >= 3 and seen[0].max() <= 9 and len(set(seen[0].tolist())) >= 5
    assert (seen[1] == 5).all()


class JoinedPointMass:
    """PointMass lanes in independent parts (each with its global lane ids), stepped all at once here."""

    def __init__(self, sizes=(3, 5)):
        self.parts = np.split(np.arange(sum(sizes)), np.cumsum(sizes)[:-1])
        self.subs = [PointMass(n) for n in sizes]
        for sub, ids in zip(self.subs, self.parts):
            sub.lane_ids = ids
        self.num_envs, self.obs_dim, self.act_dim = sum(sizes), 2, 1

    def reset(self, seed=None, options=None):
        obs = [s.reset(seed=seed + i)[0] for i, s in enumerate(self.subs)]
        return np.concatenate(obs), {"levels": np.zeros(self.num_envs)}

    def step(self, a):
        outs = [s.step(a[ids]) for s, ids in zip(self.subs, self.parts)]
        info = {key: np.concatenate([o[4][key] for o in outs]) for key in outs[0][4]}
        return tuple(np.concatenate([o[j] for o in outs]) for j in range(4)) + (info,)


class SplitPointMass(JoinedPointMass):
    """The same lanes rolled out part by part, like ballu.VecBallu's worker processes (`run`)."""

    def run(self, fn, args):
        return [fn(sub, *a) for sub, a in zip(self.subs, args)]


@pytest.mark.parametrize("text", ["10:5", "abc", "80", "-1", "3:", ":4"])
def test_experiments_start_level_argument_errors_name_the_range(text):
    import argparse
    with pytest.raises(argparse.ArgumentTypeError, match="0 <= LOW <= HIGH <= 74"):
        ppo_ballu.start_levels(text)
    assert ppo_ballu.start_levels("3:9") == (3, 9) and ppo_ballu.start_levels("7") == 7
    assert ppo_ballu.start_levels("5:5") == (5, 5)
    assert ppo_ballu.start_levels("spread") == "spread" and ppo_ballu.start_levels("task") == "task"
    assert ballu.spread_start_levels("obstacle") == (0, 28) and ballu.spread_start_levels("ramp", 2) == (0, 2)
    # the measured per-task default (docs/ppo_protocol): spread on the ramp, level 0 on the obstacle
    assert ballu.train_start_levels("ramp") == (0, 40) and ballu.train_start_levels("obstacle") == 0
    assert policies.start_levels("ramp", run_all.SMOKE) == (0, 2) and policies.start_levels("obstacle", run_all.QUICK) == 0


def test_ppo_rollout_split_over_workers_equals_one_process():
    """Each worker rolling out its own lanes with a policy copy gives the buffers of one in-process rollout
    (the noise is per lane), across episode ends (40-step episodes, 50 steps: time-limit bootstraps included)."""
    cfg = ppo.PPOConfig(num_envs=8, num_steps=50)
    out = []
    for env in (JoinedPointMass(), SplitPointMass()):
        obs, _ = env.reset(seed=5)
        torch.manual_seed(0)
        pol, norm = ppo.make_policy("mlp", 2, 1, cfg), ppo.RunningNorm(2)
        norm.update(obs)
        out.append(ppo.rollout("mlp", pol, norm, env, obs, 50, cfg, noise_seed=3) + (norm,))
    (b1, o1, _, r1, n1), (b2, o2, _, r2, n2) = out
    for k in b1:
        np.testing.assert_allclose(b1[k], b2[k], rtol=1e-5, atol=1e-6, err_msg=k)
    np.testing.assert_allclose(o1, o2, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(sorted(r1), sorted(r2), rtol=1e-5)
    np.testing.assert_allclose(n1.mean, n2.mean, rtol=1e-6)   # the normaliser saw every new observation
    assert n1.count == pytest.approx(1e-4 + 8 * 51)
    assert len(r1) == 8 and b1["done"].sum() == 8
    # the stored log-probability (computed from the noise) is that of the stored action under N(mu, std)
    logp = torch.distributions.Normal(torch.from_numpy(b1["mu"]), pol.log_std.exp().detach()).log_prob(
        torch.from_numpy(b1["act"])).sum(-1).numpy()
    np.testing.assert_allclose(b1["logp"], logp, rtol=1e-4, atol=1e-4)


def test_ppo_vecballu_rollout_in_workers_equals_one_process():
    """ppo's rollout with a policy copy in each of 2 VecBallu workers gives what one process gives."""
    cfg, bcfg = ppo.PPOConfig(num_envs=4, num_steps=6), BalluConfig(task="ramp")
    torch.manual_seed(0)
    obs_dim, act_dim = ballu.dims(bcfg)
    pol = ppo.make_policy("mlp", obs_dim, act_dim, cfg)
    out = []
    for env in (ballu.make_env(4, 1, bcfg), ballu.VecBallu(4, 2, bcfg)):
        try:
            obs, _ = env.reset(seed=2, options={"design_sampler": ballu.FixedDesign(BASELINE)})
            norm = ppo.RunningNorm(obs_dim)
            norm.update(obs)
            out.append(ppo.rollout("mlp", pol, norm, env, obs, 6, cfg, noise_seed=1))
            if hasattr(env, "run"):
                with pytest.raises(ValueError, match="one argument tuple per worker"):
                    env.run(ppo._random_steps, [(1, 0.5, 0.5, 0)])
        finally:
            env.close()
    for k in out[0][0]:
        np.testing.assert_allclose(out[0][0][k], out[1][0][k], rtol=1e-4, atol=1e-5, err_msg=k)
    np.testing.assert_allclose(out[0][1], out[1][1], rtol=1e-4, atol=1e-5)


def test_ballu_score_in_workers_equals_score_in_one_process():
    """ballu.score in the shared worker pool (each worker plays its designs with its own policy copy) gives
    exactly the scores of one process, for a per-lane scripted gait and a learned policy; the pool is reused."""
    cfg = replace(BalluConfig(), episode_steps=60)
    rng = np.random.default_rng(4)
    designs = np.column_stack([rng.uniform(0.3, 0.5, (6, 2)), rng.uniform(0.75, 0.9, 6), rng.uniform(0.001, 0.1, 6)])
    torch.manual_seed(3)
    learned = ppo.PolicyFn(ppo.make_policy("mlp", ballu.OBS_DIM, ballu.ACT_DIM, ppo.PPOConfig()),
                           ppo.RunningNorm(ballu.OBS_DIM))
    pump = ballu.PumpGait([6, 8, 10, 12, 14, 16], ["sync", "alternate"] * 3)
    for policy in (pump, learned):
        one, x1 = ballu.score(policy, designs, "obstacle", episodes=2, cfg=cfg, workers=1, final_x=True)
        two, x2 = ballu.score(policy, designs, "obstacle", episodes=2, cfg=cfg, workers=2, final_x=True)
        np.testing.assert_array_equal(one, two)
        np.testing.assert_array_equal(x1, x2)                  # the same trajectories, to the last bit
        assert np.unique(x1[:, 0]).size == len(x1)             # ... and they did differ between lanes
        if policy is learned:   # row by row: a design's score does not depend on who shares its call
            _, x3 = ballu.score(policy, designs[1:4], "obstacle", episodes=2, cfg=cfg, workers=2, final_x=True)
            np.testing.assert_array_equal(x1[1:4], x3)
    assert ballu.shared_pool(2) is ballu.shared_pool(2)


# where HysteresisPump reads the knee angles and the last action: the paper form's layout (obs="paper")
PUMP_KNEES, PUMP_LAST = ([ballu.obs_names(BalluConfig(obs="paper")).index(n) for n in names]
                         for names in (("q_knee_l", "q_knee_r"), ("a_l", "a_r")))


class HysteresisPump:
    """A pure pump gait for tests: keep pulling both knees (last action 1, read from the observation) until a knee
    bends past 1.7 rad, keep releasing until it is straighter than 0.6 rad. No state of its own, so
    ballu.score may reuse its episodes. The baseline design hops over low boxes with it."""
    pure = True

    def __call__(self, obs):
        o = np.asarray(obs)
        q, last = o[:, PUMP_KNEES], o[:, PUMP_LAST]
        return np.where(last > 0.5, q < 1.7, q < 0.6).astype(float)


@pytest.mark.slow
def test_ballu_score_reuse_replays_known_levels_exactly(monkeypatch):
    """score(reuse=True) plays each level of a design's walk once: J and every episode's final x equal playing
    every episode, on walks that clear the box and come back to a level they played (a swing between two levels
    or a hold), that sit on the floor level 0, and on the ramp (the wedge is rebuilt each level), with fewer
    physics steps; reuse needs unit level steps."""
    steps = [0]
    step_simulation = pybullet.stepSimulation

    def counted(*args, **kw):
        steps[0] += 1
        return step_simulation(*args, **kw)

    monkeypatch.setattr(ballu.pybullet, "stepSimulation", counted)
    designs = np.array([ballu.BASELINE, ballu.D2_CENTRE])
    for task, start, episodes in (("obstacle", 6, 5), ("ramp", 2, 5)):
        out, cost, played = {}, {}, {}
        for reuse in (False, True):
            steps[0], stats = 0, {}
            out[reuse] = ballu.score(HysteresisPump(), designs, task, episodes=episodes, start_level=start,
                                     final_x=True, reuse=reuse, stats=stats, cfg=BalluConfig(obs="paper"))
            cost[reuse], played[reuse] = steps[0], stats["episodes_played"]
        assert played[False] == episodes * len(designs) > played[True]   # what a J costs, for run_all's plan
        np.testing.assert_array_equal(out[True][0], out[False][0])
        np.testing.assert_array_equal(out[True][1], out[False][1])
        x = out[False][1]
        assert len(set(x[1])) == 1 and x[1, 0] < 0.5, x          # the D2 centre sits on level 0
        assert cost[True] < cost[False], (task, cost)
        if task == "obstacle":   # the baseline clears the box (x > 1), then returns to a level it played
            assert x[0].max() > 1.0 and len(set(x[0])) < len(x[0]), x
    with pytest.raises(ValueError, match="reuse=True needs unit level steps"):
        ballu.score(HysteresisPump(), designs[:1], "obstacle", level_steps=(2, 1), reuse=True)


def test_ballu_score_of_a_design_does_not_depend_on_its_call_mates():
    """A lane's trajectory can depend on its PyBullet world-mates once robots reach the box, so score gives each
    design a world of its own: the same trajectories with 1 or 2 workers, and for a design scored with 4 others
    or with 2."""
    rng = np.random.default_rng(4)
    designs = np.column_stack([np.full((5, 2), 0.45), rng.uniform(0.75, 0.9, 5), rng.uniform(0.001, 0.1, 5)])
    periods, modes = [40, 36, 40, 32, 40], ["sync", "sync", "alternate", "sync", "sync"]
    runs = [ballu.score(ballu.PumpGait(periods, modes), designs, "obstacle", episodes=1, start_level=10,
                        workers=w, final_x=True)[1] for w in (1, 2)]
    few = ballu.score(ballu.PumpGait(periods[:3], modes[:3]), designs[:3], "obstacle", episodes=1, start_level=10,
                      final_x=True)[1]
    np.testing.assert_array_equal(runs[0], runs[1])
    np.testing.assert_array_equal(runs[0][:3], few)
    assert runs[0][0, 0] > 1.0                      # the first robot did get past the box (contact physics)


@pytest.mark.parametrize("argv, msg", [(["--steps", "-5"], "--steps -5 must be >= 1"),
                                       (["--envs", "2", "--workers", "3"], "--workers 3 must be in [1, --envs 2]"),
                                       (["--rollout", "0"], "--rollout 0 must be >= 1"),
                                       (["--seed", "-1"], "--seed -1 must be in [0, 2**64 - 1]"),
                                       (["--entropy", "nan"], "--entropy nan must be finite"),
                                       (["--init-mean", "inf"], "--init-mean inf must be finite"),
                                       (["--design", "foo"], "design 'foo': 'foo' is not name=value"),
                                       (["--design", "1,2"], "design '1,2': '1' is not name=value"),
                                       (["--design", "gcr=nan"], "design 'gcr=nan': gcr=nan is outside"),
                                       (["--design", "l=2"], "design 'l=2': l_f=2.0 is outside [0.05, 1.0]")])
def test_experiments_ppo_ballu_rejects_out_of_range_numbers(argv, msg, tmp_path, capsys):
    """experiments.ppo_ballu train: one line naming the option and its range, and nothing written."""
    with pytest.raises(SystemExit) as e:
        ppo_ballu.main(["train", "--out", str(tmp_path / "out"), *argv])
    assert e.value.code == 2 and msg in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_experiments_ppo_protocol_pairs_each_setting_with_the_first_by_seed():
    """The screen's paired column: per seed, setting minus the first setting at the last milestone; best
    policies' J and last policies' J (a result from before the best-policy rule counts its J as the last)."""
    res = {("a", "obstacle", 0): [{"mean_J": 10.0}], ("a", "obstacle", 1): [{"mean_J": 14.0}],
           ("b", "obstacle", 0): [{"mean_J": 13.0, "mean_J_last": 11.0}],
           ("b", "obstacle", 1): [{"mean_J": 15.0, "mean_J_last": 16.0}]}
    # best: 3, 1 -> 2.0 +- 1.0; last: 1, 2 -> 1.5 +- 0.5
    assert ppo_protocol._paired(res, "b", "a", "obstacle", (0, 1)) == "2.0 +- 1.0 / 1.5 +- 0.5"
    assert ppo_protocol._paired(res, "a", "a", "obstacle", (0, 1)) == "-"


def test_experiments_ppo_protocol_names_the_runs_a_kill_resumed(tmp_path):
    """A training log whose wall clock starts again: at a milestone's checkpoint (1,001,472 steps, the first whole
    update past 1 M) that is the protocol's schedule; at 368,640 it is a kill, which the table names."""
    log = tmp_path / "lr_cap" / "obstacle" / "seed2" / "log.csv"
    log.parent.mkdir(parents=True)
    steps = np.arange(2048, 1_200_000, 2048)
    wall = np.concatenate([np.arange(1, 181), np.arange(1, 310), np.arange(1, 1 + len(steps) - 489)]).astype(float)
    log.write_text("steps,wall_s\n" + "".join(f"{s},{w}\n" for s, w in zip(steps, wall)))
    assert logs.resume_points(str(log)) == [368_640, 1_001_472]
    assert ppo_protocol.kill_resumes(str(log), [1_000_000, 2_000_000]) == [368_640]
    line = ppo_protocol._resume_lines(str(tmp_path), [("lr_cap", "obstacle", 2), ("lr_cap", "obstacle", 0)],
                                      [1_000_000])
    assert line.startswith("Resumed after a kill") and "lr_cap obstacle seed 2 at 368,640 steps." in line
    assert ppo_protocol._resume_lines(str(tmp_path), [("lr_cap", "obstacle", 0)], [1_000_000]) == ""
    # asked for fewer milestones than the run went on from: the run's own results count as its schedule
    assert ppo_protocol.kill_resumes(str(log), []) == [368_640, 1_001_472]
    (log.parent / "result_1000000.json").write_text("{}")
    assert ppo_protocol.kill_resumes(str(log), []) == [368_640]


@pytest.mark.slow
def test_experiments_ppo_protocol_tables_every_setting_and_resumes(tmp_path):
    """The PPO protocol on a tiny budget: a row per setting and task with mean +- SE over seeds, the curve
    figure, a rerun that trains nothing (every milestone's result is kept), one copy of each checkpoint."""
    kw = dict(settings=("before",), tasks=("obstacle",), seeds=(0, 1), milestones=(100, 256), n_designs=2,
              episodes=1, workers=1, base_cfg=ppo.PPOConfig(num_envs=4, num_steps=16), progress=None)
    text = ppo_protocol.protocol(str(tmp_path), **kw)
    assert "| before | obstacle | " in text and "J at 256 steps" in text and " +- " in text
    assert (tmp_path / "protocol_curves.png").exists() and (tmp_path / "before/obstacle/seed1/result_256.json").exists()
    seed0 = tmp_path / "before/obstacle/seed0"
    assert sorted(p.name for p in seed0.glob("*.pt")) == ["policy_100.pt", "policy_256.pt"]   # 100: 2 updates, 128
    best = json.loads((seed0 / "result_256.json").read_text())   # the best policy is one of the two, not a copy
    assert (best["best_file"], best["best_steps"]) in (("policy_100.pt", 128), ("policy_256.pt", 256)), best
    stamp = os.path.getmtime(seed0 / "policy_256.pt")
    assert ppo_protocol.protocol(str(tmp_path), **kw) == text
    assert os.path.getmtime(seed0 / "policy_256.pt") == stamp
    with pytest.raises(ValueError, match="unknown"):
        ppo_protocol.protocol(str(tmp_path), **dict(kw, settings=("nope",)))
    # rescore: a result scored on another CPU model is scored again here from its milestone checkpoint, kept
    # beside the first score, and tabled in its place; here the same machine must give the same J
    path = tmp_path / "before/obstacle/seed1/result_256.json"
    res = json.loads(path.read_text())
    path.write_text(json.dumps({**res, "cpu": "another CPU", "mean_J": -1.0}))
    assert "another CPU" in ppo_protocol.protocol(str(tmp_path), **kw)     # without rescore: the file's own score
    again = ppo_protocol.protocol(str(tmp_path), **dict(kw, rescore=True, table="here"))
    assert again == text + (f"Rescored here: 1 obstacle results first scored on another CPU; mean J moved "
                            f"{res['mean_J'] + 1:+.2f} on average, at most {abs(res['mean_J'] + 1):.2f}.\n")
    assert (tmp_path / "here.md").read_text() == again
    kept = json.loads(path.read_text())
    assert kept["mean_J"] == -1.0 and kept["rescored"][ppo_protocol.cpu_model()]["J"] == res["J"]
    stamp = os.path.getmtime(path)
    assert ppo_protocol.protocol(str(tmp_path), **dict(kw, rescore=True)) == again and os.path.getmtime(path) == stamp
    # fresh designs: each milestone's best policy scored once more on designs no run was chosen on, kept, not redone
    fresh = ppo_protocol.protocol(str(tmp_path), **dict(kw, fresh=2, table="fresh"))
    res = json.loads((seed0 / "result_256.json").read_text())
    assert res["fresh"]["n"] == 2 and len(res["fresh"]["J"]) == 2 and "2 fresh designs (seed 17)" in fresh
    designs = ppo_protocol.protocol_designs(2, ppo_protocol.FRESH_DESIGN_SEED)
    J = ballu.score(ppo.load_policy(str(seed0 / res["best_file"])), designs, "obstacle", episodes=1)
    assert J.tolist() == res["fresh"]["J"]
    stamp = os.path.getmtime(seed0 / "result_256.json")
    assert ppo_protocol.protocol(str(tmp_path), **dict(kw, fresh=2, table="fresh")) == fresh
    assert os.path.getmtime(seed0 / "result_256.json") == stamp
    with pytest.raises(ValueError, match="single design"):
        ppo_protocol.protocol(str(tmp_path), **dict(kw, fresh=2, design=[0.45, 0.45, 0.8, 0.005]))


def test_ppo_gaussian_log_prob_and_entropy_match_torch_normal():
    """The update's hand-written log N(a; mu, std) and entropy equal torch.distributions.Normal's."""
    g = torch.Generator().manual_seed(0)
    act, mu, log_std = torch.randn(7, 2, generator=g), torch.randn(7, 2, generator=g), torch.randn(2, generator=g)
    ref = torch.distributions.Normal(mu, log_std.exp())
    torch.testing.assert_close(ppo.gaussian_log_prob(act, mu, log_std), ref.log_prob(act).sum(-1))
    torch.testing.assert_close(ppo.entropy_bonus(mu, log_std, act, mu, log_std.exp(), ppo.PPOConfig()),
                               ref.entropy().sum(-1)[0])


@pytest.mark.parametrize("m, s", [(0.0, 2.0), (1.5, 0.7), (-3.0, 1.2)])
def test_ppo_squashed_entropy_matches_numerical_integration(m, s):
    """The squashed policy's entropy bonus (its Gaussian entropy plus E log sigmoid'(u), on the minibatch's
    samples) equals -int p(a) log p(a) da of a = sigmoid(u), u ~ N(m, s), integrated numerically, with
    p(a) = N(logit a; m, s) / (a (1 - a)) (change of variables). Both action dims alike: twice the 1-D value."""
    from scipy import integrate, special
    pdf = lambda a: stats.norm.pdf(special.logit(a), m, s) / (a * (1 - a))
    ref = integrate.quad(lambda a: -pdf(a) * math.log(pdf(a)) if pdf(a) > 0 else 0.0, 0, 1, limit=400,
                         points=[special.expit(m)])[0]
    n = 200_000
    eps = torch.from_numpy(np.random.default_rng(0).standard_normal((n, 2)).astype(np.float32))
    mu, log_std = torch.full((n, 2), m), torch.full((2,), math.log(s))
    got = ppo.entropy_bonus(mu, log_std, mu + s * eps, mu, torch.full((n, 2), s), ppo.PPOConfig(squash=True))
    assert abs(float(got) - 2 * ref) < 0.01


def test_ppo_squash_sends_sigmoid_actions_and_policy_fn_plays_the_squashed_mean():
    """squash=True: the env gets sigmoid(u) in (0, 1); the deterministic policy plays sigmoid(mean); off, u."""
    u = np.array([[-30.0, 0.0], [2.0, 30.0]])
    np.testing.assert_allclose(ppo.to_env(u, ppo.PPOConfig(squash=True)), [[0.0, 0.5], [1 / (1 + math.exp(-2)), 1.0]],
                               atol=1e-12)
    assert ppo.to_env(u, ppo.PPOConfig()) is u
    torch.manual_seed(0)
    pol, norm = ppo.make_policy("mlp", 5, 2), ppo.RunningNorm(5)
    obs = np.random.default_rng(0).standard_normal((3, 5))
    plain, squashed = ppo.PolicyFn(pol, norm)(obs), ppo.PolicyFn(pol, norm, ppo.PPOConfig(squash=True))(obs)
    np.testing.assert_allclose(squashed, 1 / (1 + np.exp(-plain)), rtol=1e-12)


def test_ppo_split_clip_bounds_actor_and_critic_gradients_apart():
    """split_clip: each of actor and critic is clipped to max_grad_norm on its own, so a large critic gradient
    no longer shrinks the actor's; the joint clip [facts] scales both by the same factor."""
    torch.manual_seed(0)
    for kind in ("mlp", "moe"):
        pol = ppo.make_policy(kind, ballu.OBS_DIM, 2)
        critic = list(pol.critic.parameters())
        actor = [p for p in pol.parameters() if all(p is not c for c in critic)]
        norm_of = lambda ps: float(torch.sqrt(sum((p.grad ** 2).sum() for p in ps)))
        for split in (False, True):
            for p in actor:
                p.grad = torch.full_like(p, 1e-4)
            for p in critic:
                p.grad = torch.full_like(p, 1.0)
            a0 = norm_of(actor)
            ppo.clip_gradients(pol, ppo.PPOConfig(split_clip=split))
            assert norm_of(critic) == pytest.approx(0.5, rel=1e-4)
            if split:
                assert norm_of(actor) == pytest.approx(a0, rel=1e-5)   # small: left alone
            else:
                assert norm_of(actor) < a0 / 50                         # shrunk with the critic


def test_ppo_moe_gate_weights_sum_to_one_and_get_gradients():
    torch.manual_seed(0)
    cfg = ppo.PPOConfig()
    pol = ppo.MoEActorCritic(ballu.OBS_DIM, 2, cfg)
    obs = torch.randn(64, ballu.OBS_DIM)
    w = pol.gate_weights(obs[:, -4:])
    assert w.shape == (64, cfg.moe_experts)
    np.testing.assert_allclose(w.sum(1).detach().numpy(), 1.0, atol=1e-6)
    loss = ppo.gaussian_log_prob(torch.ones(64, 2), pol.mean(obs), pol.log_std).sum() + pol.aux_loss(obs)
    loss.backward()
    g = [p.grad for p in pol.gate.parameters()]
    assert all(x is not None for x in g) and sum(x.abs().sum() for x in g) > 0
    # the load-balance term is zero for uniform use and positive otherwise
    assert float(pol.aux_loss(obs).detach()) >= 0.0


# ==========================================================================================================
# ges.py: the box, initialisation, coverage, refit, router, the loop, resume, executors
# ==========================================================================================================
MC_SD = lambda p, n: math.sqrt(p * (1 - p) / n)  # noqa: E731  standard error of an MC fraction


# =========================================================================================================
# ges: the box GES works in (the BALLU design spaces are tested with ballu.py)
# =========================================================================================================

def test_ges_unit_roundtrip_and_uniform_sampling():
    s = D3_BOX
    x = ges.rng_for(0).random((1000, 3))
    theta = s.from_unit(x)
    np.testing.assert_allclose(s.to_unit(theta), x, atol=1e-12)
    s.validate(theta)  # round-off of the round trip is not an error
    np.testing.assert_allclose(s.to_unit(s.lo), 0)
    np.testing.assert_allclose(s.to_unit(s.hi), 1)
    u = s.sample_uniform(ges.rng_for(1), 20_000)
    assert np.all(u >= s.lo) and np.all(u <= s.hi)
    np.testing.assert_allclose(s.to_unit(u).mean(0), 0.5, atol=0.01)


@pytest.mark.parametrize("call, words", [
    (lambda: ballu.d2().validate([0.95, 0.05]), ["gcr=0.95", "0.72", "0.9"]),
    (lambda: ballu.d2().validate([[0.8, 0.05], [0.8, 0.2]]), ["spcf=0.2", "row 1", "0.001", "0.1"]),
    (lambda: ballu.d2().validate([0.8, float("nan")]), ["spcf=nan"]),
    (lambda: ballu.d2().validate([0.8, 0.05, 0.3]), ["shape", "d=2"]),
    (lambda: ballu.d2(task="walk"), ["task='walk'"]),
    (lambda: ballu.d3(setup="wide"), ["setup='wide'", "'table'", "'authors'"]),
    (lambda: ballu.d2(setup="authors"), ["setup='authors'", "task"]),
    (lambda: ballu.DesignSpace(("gcr",), (0.9,), (0.8,), {"l_f": .4, "l_t": .4, "spcf": .01}),
     ["gcr", "low < high"]),
    (lambda: ballu.DesignSpace(("gcr",), (0.7,), (0.8,), {"l_f": .4}), ["l_t"]),
    (lambda: ges.GESConfig(K=0), ["K=0", ">= 1"]),
    (lambda: ges.GESConfig(init="kmeans"), ["init='kmeans'", "fps+lloyd"]),
    (lambda: ges.GESConfig(router="nearest"), ["router='nearest'", "density"]),
    (lambda: ges.GESConfig(tau=1.5), ["tau=1.5", "(0, 1)"]),
    (lambda: ges.GESConfig(n_probe=100, probe_pool=50), ["probe_pool=50", "n_probe"]),
    (lambda: ges.init_centers("hex", 3, 2, ges.rng_for(0)), ["method='hex'"]),
])
def test_ges_bad_input_names_parameter_value_and_range(call, words):
    with pytest.raises(ValueError) as err:
        call()
    for w in words:
        assert w in str(err.value), (w, str(err.value))


def test_ges_config_defaults_follow_paper_and_facts():
    c = ges.GESConfig()
    assert (c.K, c.n_probe, c.probe_pool, c.band_lo, c.band_hi, c.n_init_designs) == (3, 100, 2000, -2.5, -0.5, 50)
    assert (c.n_mc, c.target_coverage, c.init_coverage, c.max_rounds, c.lloyd_iters, c.fps_pool) == \
        (10_000, 0.95, 0.12, 20, 12, 10_000)
    assert c.tau == math.exp(-2) and c.var_floor == pytest.approx(0.01 ** 2)
    assert (c.init, c.router) == ("fps+lloyd", "density")


# =========================================================================================================
# ges: MC coverage (eq. 8-9)
# =========================================================================================================
@pytest.mark.parametrize("mu, sigma", [(0.5, 0.1), (0.1, 0.1), (0.9, 0.2), (0.3, 0.5)])
def test_ges_coverage_1d_matches_clipped_interval(mu, sigma):
    pts = ges.mc_points(0, 10_000, 1)
    c = ges.coverage(np.array([[mu]]), np.array([[sigma]]), pts)
    exact = min(1.0, mu + 2 * sigma) - max(0.0, mu - 2 * sigma)  # |x - mu| < 2 sigma  <=>  f > e^-2
    assert abs(c - exact) < 4 * MC_SD(exact, 10_000) + 1e-9, (c, exact)


def test_ges_coverage_matches_paper_definition_pointwise():
    rng = ges.rng_for(3)
    mu, sigma, pts = rng.random((4, 3)), 0.05 + 0.2 * rng.random((4, 3)), rng.random((500, 3))
    covered = [max(math.exp(-sum((p[d] - mu[k, d]) ** 2 / (2 * sigma[k, d] ** 2) for d in range(3)))
                   for k in range(4)) > math.exp(-2) for p in pts]
    assert ges.coverage(mu, sigma, pts) == pytest.approx(np.mean(covered), abs=1e-12)


def test_ges_coverage_rises_monotonically_with_sigma():
    rng = ges.rng_for(4)
    mu, pts = rng.random((3, 2)), ges.mc_points(4, 10_000, 2)
    cs = [ges.coverage(mu, np.full((3, 2), s), pts) for s in np.linspace(0.01, 0.6, 30)]
    assert np.all(np.diff(cs) >= 0) and cs[0] < 0.05 and cs[-1] == 1.0


# =========================================================================================================
# ges: initialisation (paper Sec. IV-B, Table III; facts)
# =========================================================================================================
def test_ges_lloyd_k4_converges_to_quarter_points():
    pool = ges.rng_for(5).random((10_000, 2))
    start = np.array([[0.05, 0.1], [0.9, 0.02], [0.1, 0.95], [0.6, 0.7]])
    c = ges.lloyd(start, pool, 12)
    np.testing.assert_allclose(np.sort(c, axis=0), [[0.25, 0.25]] * 2 + [[0.75, 0.75]] * 2, atol=0.02)
    c2 = ges.init_centers("fps+lloyd", 4, 2, ges.rng_for(6))  # the default pipeline lands there too
    assert sorted(map(tuple, np.round(c2 * 4) / 4)) == [(0.25, 0.25), (0.25, 0.75), (0.75, 0.25), (0.75, 0.75)]


def _covering_radius(c, d):
    g = np.linspace(0, 1, 201 if d == 2 else 41)
    x = np.stack(np.meshgrid(*[g] * d, indexing="ij"), -1).reshape(-1, d)
    return np.sqrt(((x[:, None, :] - c[None]) ** 2).sum(-1).min(1)).max()


@pytest.mark.parametrize("d", [2, 3])
@pytest.mark.parametrize("K", [3, 4, 5, 6])
def test_ges_fps_lloyd_has_smaller_covering_radius(K, d):
    seeds = range(5)
    r = {m: [_covering_radius(ges.init_centers(m, K, d, ges.rng_for(s)), d) for s in seeds]
         for m in ("fps+lloyd", "random", "grid")}
    assert max(r["fps+lloyd"]) < min(r["random"]), r  # worst FPS+Lloyd beats the best random draw
    if (K, d) == (4, 2):
        # Genuine exception, kept visible: the 2x2 grid IS the quarter-point Lloyd fixed point (radius
        # sqrt(2)/4 = 0.354); FPS+Lloyd reaches it only up to pool noise (0.357..0.363 here).
        assert r["grid"][0] == pytest.approx(math.sqrt(2) / 4, abs=1e-9)
        assert max(r["fps+lloyd"]) < r["grid"][0] * 1.03, r
    else:
        assert max(r["fps+lloyd"]) < r["grid"][0], r


def test_ges_grid_is_unbalanced_for_odd_k():
    np.testing.assert_allclose(ges.grid_centers(3, 2), [[0.25, 0.25], [0.25, 0.75], [0.75, 0.25]])
    assert ges.grid_centers(8, 3).shape == (8, 3) and len(np.unique(ges.grid_centers(8, 3), axis=0)) == 8


def test_ges_fps_starts_at_random_pool_point_and_spreads():
    pool = ges.rng_for(7).random((10_000, 2))
    a = ges.farthest_point_sampling(pool, 3, ges.rng_for(8))
    b = ges.farthest_point_sampling(pool, 3, ges.rng_for(9))
    assert all(any(np.array_equal(p, q) for q in pool) for p in a)  # centres are pool points
    assert not np.array_equal(a[0], b[0])  # the start depends on the rng
    assert min(np.linalg.norm(a[i] - a[j]) for i in range(3) for j in range(i)) > 0.5


def test_ges_sigma_calibration_hits_12_percent():
    for K, d in ((3, 2), (6, 3)):
        mu = ges.init_centers("fps+lloyd", K, d, ges.rng_for(10))
        sigma = ges.calibrate_sigma(mu, ges.mc_points(10, 10_000, d), 0.12)
        assert np.allclose(sigma, sigma[0, 0])  # isotropic, shared (proportional to 1/K^(1/d))
        assert ges.coverage(mu, sigma, ges.mc_points(10, 10_000, d)) == pytest.approx(0.12, abs=2e-4)
        # the calibration set is itself an MC sample: the true coverage (200k independent points, SE 0.0007)
        # lies within its MC error (measured 0.1223 for K=3, 0.1257 for K=6)
        true = ges.coverage(mu, sigma, ges.rng_for(999).random((200_000, d)))
        assert abs(true - 0.12) < 4 * MC_SD(0.12, 10_000), true


def test_ges_refit_equals_numpy_with_floor():
    rng = ges.rng_for(11)
    eta = np.column_stack([rng.random(80), np.full(80, 0.3), 0.3 + 0.005 * rng.random(80)])
    mu, sigma = ges.refit(eta, 1e-4)
    np.testing.assert_allclose(mu, np.mean(eta, axis=0), rtol=0, atol=1e-15)
    np.testing.assert_allclose(sigma ** 2, np.maximum(np.var(eta, axis=0), 1e-4), rtol=1e-12)
    assert sigma[1] == pytest.approx(0.01) and sigma[2] == pytest.approx(0.01)  # floored axes
    assert sigma[0] ** 2 == pytest.approx(np.var(eta[:, 0]))                    # unfloored axis


# =========================================================================================================
# ges: probes and density router (eq. 6, eq. 10)
# =========================================================================================================
def test_ges_probes_are_the_outermost_in_band_points():
    mu, sigma = np.array([[0.3, 0.3], [0.7, 0.6]]), np.full((2, 2), 0.08)
    p = ges.sample_probes(mu, sigma, ges.rng_for(12), 100, 2000, (-2.5, -0.5))
    g = ges.log_f(p, mu, sigma).max(1)
    assert p.shape == (100, 2) and np.all((g > -2.5) & (g < -0.5))
    pool = ges.rng_for(12).random((2000, 2))  # same draw as inside: the chosen are the lowest in-band g
    gp = ges.log_f(pool, mu, sigma).max(1)
    in_band = np.sort(gp[(gp > -2.5) & (gp < -0.5)])
    np.testing.assert_allclose(np.sort(g), in_band[:100])
    # band nearly empty (tiny territory): top up with the points farthest from every territory
    q = ges.sample_probes(mu, np.full((2, 2), 1e-3), ges.rng_for(13), 100, 2000, (-2.5, -0.5))
    assert len(q) == 100 and np.linalg.norm(q - mu[0], axis=1).min() > 0.1


def test_ges_density_router_matches_scipy():
    rng = ges.rng_for(14)
    mu, sigma, x = rng.random((5, 3)), 0.03 + 0.3 * rng.random((5, 3)), rng.random((2000, 3))
    ref = np.argmax([multivariate_normal(mu[k], np.diag(sigma[k] ** 2)).logpdf(x) for k in range(5)], axis=0)
    np.testing.assert_array_equal(ges.route_unit(x, mu, sigma), ref)
    np.testing.assert_allclose(ges.log_density(x, mu, sigma)[:, 2],
                               multivariate_normal(mu[2], np.diag(sigma[2] ** 2)).logpdf(x), rtol=1e-10)


def test_ges_density_router_broad_vs_narrow():
    mu = np.array([[0.45, 0.5], [0.5, 0.5]])          # 0 broad, 1 narrow
    sigma = np.array([[0.3, 0.3], [0.02, 0.02]])
    x = np.array([[0.5, 0.5],      # at the narrow centre
                  [0.53, 0.5],     # 1.5 sigma out of narrow: unnormalised f says broad, the density says narrow
                  [0.9, 0.9],      # far out: broad
                  [0.45, 0.1]])
    ks = ges.route_unit(x, mu, sigma)
    ref = np.argmax([multivariate_normal(m, np.diag(s ** 2)).pdf(x) for m, s in zip(mu, sigma)], axis=0)
    np.testing.assert_array_equal(ks, ref)
    np.testing.assert_array_equal(ks, [1, 1, 0, 0])
    assert np.argmax(ges.log_f(x[1:2], mu, sigma)) == 0  # the determinant is what makes point 1 narrow's


# =========================================================================================================
# ges: the loop on a synthetic landscape (Alg. 1)
# =========================================================================================================
SITES = np.array([[0.15, 0.2], [0.85, 0.35], [0.4, 0.85]])  # = ges_demo.DEMO_SITES_2D, repeated to pin the test


def _land(space=None):
    return ges_demo.PlantedLandscape(space or D2_BOX, SITES)


def _run(run_dir, land=None, executor=None, train=None, config=None, seed=0):
    land = land or _land()
    return ges.run_ges(land.space, train or land.train, land.score, str(run_dir), config or ges.GESConfig(K=3),
                       seed, executor or ges.SerialExecutor(), progress=None)


@pytest.fixture(scope="module")
def synthetic_run(tmp_path_factory):
    return _run(tmp_path_factory.mktemp("ges_synth"))


def test_ges_synthetic_trainer_really_improves(tmp_path):
    land = _land()
    sampler = ges.GaussianSampler(np.array([0.2, 0.25]), np.array([0.1, 0.1]), land.space, seed=1)
    designs = sampler(ges.rng_for(2), 500)
    before = land.score(0, None, designs).mean()
    land.train(0, 0, sampler, None, str(tmp_path / "a.ckpt"))
    mid = land.score(0, str(tmp_path / "a.ckpt"), designs).mean()
    land.train(0, 1, sampler, str(tmp_path / "a.ckpt"), str(tmp_path / "b.ckpt"))  # warm start continues
    after = land.score(0, str(tmp_path / "b.ckpt"), designs).mean()
    assert before < mid < after
    assert np.argmax(read_json(tmp_path / "b.ckpt")["p"]) == 0  # learnt the behaviour of site 0


def test_ges_history_keeps_every_probe_score(synthetic_run):
    """Each round's history entry keeps the K x F probe score matrix: its column argmax (ties to the lower index,
    eq. 6) is the recorded winner, and each score is the specialist's own score of that probe, recomputed."""
    res, land = synthetic_run, _land()
    for h in res.history["rounds"][1:]:
        S, probes = np.array(h["probe_scores"]), np.array(h["probes_unit"])
        assert S.shape == (len(h["mu"]), len(probes)) and list(np.argmax(S, axis=0)) == h["winner"]
    h = res.history["rounds"][-1]
    ckpt = [os.path.join(res.run_dir, c) for c in h["ckpt"]]
    for k, c in enumerate(ckpt):
        np.testing.assert_array_equal(land.score(k, c, res.space.from_unit(np.array(h["probes_unit"]))),
                                      np.array(h["probe_scores"])[k])
    assert res.history["rounds"][0]["probe_scores"] == []


def test_ges_synthetic_reaches_coverage_and_specialises(synthetic_run):
    res = synthetic_run
    hist = res.history["rounds"]
    assert res.coverage >= 0.95 and res.rounds < 20, (res.coverage, res.rounds)  # measured: 96.3 % at round 15
    assert hist[0]["coverage"] == pytest.approx(0.12, abs=2e-4)
    assert [h["round"] for h in hist] == list(range(res.rounds + 1))
    assert all(sum(h["wins"]) == 100 for h in hist[1:])
    g = np.linspace(0, 1, 101)
    x = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    region, owner = _land().region(x), ges.route_unit(x, res.mu_unit, res.sigma_unit)
    owners, shares = [], []
    for b in range(3):
        counts = np.bincount(owner[region == b], minlength=3)
        owners.append(int(np.argmax(counts)))
        shares.append(counts.max() / counts.sum())
    assert sorted(owners) == [0, 1, 2], owners     # a distinct specialist owns each planted region ...
    assert min(shares) > 0.85, shares              # ... mostly (measured 0.99 / 0.93 / 0.92)


def test_ges_coverage_growth_is_set_by_probes_per_seed_design():
    """Refits average the n_init seeds with the won probes, so coverage grows with F / n_init: 16 probes
    against 8 seeds reach the stopping rule, 4 against 50 barely move a territory and hit the round cap."""
    small = ges_demo.rounds_to_coverage(2, n_init=8, n_probe=16, seeds=(0,))[0]
    diluted = ges_demo.rounds_to_coverage(2, n_init=50, n_probe=4, seeds=(0,))[0]
    assert small[1] >= 0.95 and small[0] < 20, small     # measured: 0.96 in 11 rounds
    assert diluted[0] == 20 and diluted[1] < 0.4, diluted   # stopped by the round cap, far from coverage


def test_ges_result_and_history_files(synthetic_run, tmp_path):
    res = synthetic_run
    assert os.path.exists(os.path.join(res.run_dir, "history.json"))
    with open(os.path.join(res.run_dir, "history.json")) as fh:
        assert json.load(fh) == res.history
    last = res.history["rounds"][-1]
    np.testing.assert_array_equal(res.mu_unit, last["mu_unit"])
    np.testing.assert_allclose(res.mu, res.space.from_unit(res.mu_unit))
    np.testing.assert_allclose(res.sigma, res.sigma_unit * (res.space.hi - res.space.lo))
    assert all(os.path.isabs(c) and os.path.exists(c) for c in res.ckpt)
    loaded = ges.load_result(res.run_dir)
    np.testing.assert_array_equal(loaded.sigma_unit, res.sigma_unit)
    assert loaded.history == res.history
    png = figures.plot_territories(res.history, str(tmp_path / "t.png"), background=_land().region)
    assert os.path.getsize(png) > 20_000
    again = _run(res.run_dir)  # a finished run dir returns its result without training again
    assert again.rounds == res.rounds and again.history == res.history
    # each round's tasks were timed where they ran (run_all's cost stage adds them up as core-seconds)
    spent = read_json(os.path.join(res.run_dir, "state.json"))["task_seconds"]
    assert len(spent) == res.rounds and all(len(r["train"]) == len(r["probe"]) == 3 for r in spent)
    assert res.task_seconds == pytest.approx(sum(sum(r["train"]) + sum(r["probe"]) for r in spent))
    assert res.task_seconds > 0
    assert again.task_seconds == res.task_seconds


def test_ges_routed_evaluator_density_and_oracle(synthetic_run):
    res, land = synthetic_run, _land()
    theta = res.space.sample_uniform(ges.rng_for(15), 300)
    all_scores = np.stack([land.score(k, res.ckpt[k], theta) for k in range(3)])
    ks = res.route(theta)
    J = ges.routed_evaluator(res, land.score)
    np.testing.assert_allclose(J(theta), all_scores[ks, np.arange(300)])
    assert J(theta[7]) == pytest.approx(all_scores[ks[7], 7]) and isinstance(J(theta[7]), float)
    np.testing.assert_allclose(ges.routed_evaluator(res, land.score, "oracle")(theta), all_scores.max(0))
    assert np.mean(ks == all_scores.argmax(0)) > 0.8  # the density router mostly agrees with the oracle
    with pytest.raises(ValueError, match="gcr"):
        J([0.5, 0.05])
    pickle.dumps(J)


class _FailingTrainer:
    """train_fn that raises in a given round (simulates a crash), otherwise delegates."""

    def __init__(self, inner, fail_round):
        self.inner, self.fail_round = inner, fail_round

    def __call__(self, k, round, sampler, ckpt_in, ckpt_out):
        if round == self.fail_round and k == 1:
            raise RuntimeError("simulated crash")
        return self.inner(k, round, sampler, ckpt_in, ckpt_out)


def test_ges_resume_equals_uninterrupted(synthetic_run, tmp_path):
    land = _land()
    with pytest.raises(RuntimeError, match="simulated crash"):
        _run(tmp_path, land, train=_FailingTrainer(land.train, 2))
    with open(tmp_path / "state.json") as fh:
        assert json.load(fh)["round"] == 2  # rounds 0 and 1 were saved
    counting = _FailingTrainer(land.train, fail_round=-1)
    counting.rounds = []
    resumed = _run(tmp_path, land, train=lambda k, r, *a: (counting.rounds.append(r), counting(k, r, *a)))
    assert min(counting.rounds) == 2  # completed rounds are not trained again
    ref = synthetic_run
    np.testing.assert_array_equal(resumed.mu_unit, ref.mu_unit)
    np.testing.assert_array_equal(resumed.sigma_unit, ref.sigma_unit)
    assert resumed.history == ref.history and resumed.rounds == ref.rounds
    assert [os.path.basename(c) for c in resumed.ckpt] == [os.path.basename(c) for c in ref.ckpt]
    with pytest.raises(ValueError, match="different config"):
        _run(tmp_path, land, config=ges.GESConfig(K=3, n_probe=50))


def test_ges_final_train_trains_the_final_territories_once(synthetic_run, tmp_path):
    """GESConfig.final_train: after the loop, each specialist trains once more, from its last checkpoint, on its
    final territory; the loop's territories, probes and winners stay the run's. A crash in that last training
    resumes it alone; without the option state.json has no trace of it."""
    land, ref = _land(), synthetic_run
    calls = []

    def train(k, r, sampler, ckpt_in, ckpt_out):
        calls.append((k, r, sampler.mu.copy(), sampler.sigma.copy(), ckpt_in))
        return land.train(k, r, sampler, ckpt_in, ckpt_out)
    cfg = ges.GESConfig(K=3, final_train=True)
    with pytest.raises(RuntimeError, match="simulated crash"):
        _run(tmp_path, land, train=_FailingTrainer(land.train, ref.rounds), config=cfg)
    assert json.load(open(tmp_path / "state.json"))["round"] == ref.rounds
    res = _run(tmp_path, land, train=train, config=cfg)
    assert {r for _, r, *_ in calls} == {ref.rounds} and len(calls) == 3   # the final training alone
    for k, r, mu, sigma, ckpt_in in calls:
        np.testing.assert_array_equal(mu, ref.mu_unit[k])
        np.testing.assert_array_equal(sigma, ref.sigma_unit[k])
        assert os.path.basename(ckpt_in) == os.path.basename(ref.ckpt[k])
    assert [os.path.basename(c) for c in res.ckpt] == [f"spec{k}_round{ref.rounds:02d}.ckpt" for k in range(3)]
    h, h_ref = res.history["rounds"], ref.history["rounds"]
    assert h[:-1] == h_ref[:-1] and h[-1]["final_train"] and h[-1]["ckpt"] == [os.path.join("ckpt", os.path.basename(c))
                                                                                 for c in res.ckpt]
    assert {k: v for k, v in h[-1].items() if k not in ("ckpt", "final_train")} == \
        {k: v for k, v in h_ref[-1].items() if k != "ckpt"}
    assert json.load(open(tmp_path / "state.json"))["final"] is True
    assert "final" not in json.load(open(os.path.join(ref.run_dir, "state.json")))
    assert _run(tmp_path, land, train=train, config=cfg).ckpt == res.ckpt and len(calls) == 3   # done: no retraining


def test_ges_process_pool_equals_serial(synthetic_run, tmp_path):
    with ProcessPoolExecutor(2) as pool:
        par = _run(tmp_path, executor=pool)
    np.testing.assert_array_equal(par.mu_unit, synthetic_run.mu_unit)
    np.testing.assert_array_equal(par.sigma_unit, synthetic_run.sigma_unit)
    assert par.history == synthetic_run.history
    short = ges.GESConfig(K=3, max_rounds=2)  # executor=None: the default ProcessPoolExecutor(os.cpu_count())
    land = _land()
    dflt = ges.run_ges(land.space, land.train, land.score, str(tmp_path / "d"), short, 0, None, progress=None)
    assert dflt.history["rounds"] == synthetic_run.history["rounds"][:3]


def test_ges_seed_changes_run_and_3d_runs(tmp_path):
    cfg = ges.GESConfig(K=6, max_rounds=3)
    land3 = ges_demo.PlantedLandscape(D3_BOX, ges.rng_for(12345).uniform(0.1, 0.9, (6, 3)))
    a = _run(tmp_path / "a", land3, config=cfg, seed=1)
    b = _run(tmp_path / "b", land3, config=cfg, seed=2)
    assert a.rounds == 3 and a.mu_unit.shape == (6, 3)
    assert a.history["rounds"][-1]["coverage"] > a.history["rounds"][0]["coverage"]
    assert not np.array_equal(a.mu_unit, b.mu_unit)


class _RecordingTrainer:
    """train_fn that records what GES hands it (into the checkpoint itself)."""

    def __call__(self, k, round, sampler, ckpt_in, ckpt_out):
        with open(ckpt_out, "w") as fh:
            json.dump({"k": k, "round": round, "seed": sampler.seed, "ckpt_in": ckpt_in,
                       "mu": sampler.mu.tolist(), "sigma": sampler.sigma.tolist()}, fh)


def _tied_scores(k, ckpt, designs):
    return np.zeros(len(designs))


def test_ges_train_contract_warm_start_territory_and_ties(tmp_path):
    """ckpt_in is the same specialist's previous checkpoint (None in round 0), the sampler is the current
    territory, every (round, k) gets its own seed, and tied scores go to the lowest index (eq. 6, facts)."""
    res = ges.run_ges(D2_BOX, _RecordingTrainer(), _tied_scores, str(tmp_path), ges.GESConfig(K=3, max_rounds=3),
                      5, ges.SerialExecutor(), progress=None)
    hist, seeds = res.history["rounds"], set()
    for r in range(3):
        for k in range(3):
            rec = read_json(tmp_path / "ckpt" / f"spec{k}_round{r:02d}.ckpt")
            assert (rec["k"], rec["round"]) == (k, r)
            prev = str(tmp_path / "ckpt" / f"spec{k}_round{r - 1:02d}.ckpt")
            assert rec["ckpt_in"] == (None if r == 0 else prev)
            assert rec["mu"] == hist[r]["mu_unit"][k] and rec["sigma"] == hist[r]["sigma_unit"][k]
            seeds.add(rec["seed"])
        assert hist[r + 1]["wins"] == [100, 0, 0]  # all tied -> specialist 0 wins every probe
    assert len(seeds) == 9


def test_ges_contract_violations_are_reported(tmp_path):
    land = _land()
    with pytest.raises(RuntimeError, match="did not write ckpt_out"):
        _run(tmp_path / "a", land, train=lambda *args: None)
    with pytest.raises(ValueError, match="score_fn must return 100"):
        ges.run_ges(land.space, land.train, lambda k, c, x: np.zeros(3), str(tmp_path / "b"),
                    ges.GESConfig(K=3), 0, ges.SerialExecutor(), progress=None)
    with pytest.raises(ValueError, match="seed=-1"):
        _run(tmp_path / "c", land, seed=-1)
    with pytest.raises(RuntimeError, match="simulated crash"):  # crash in round 0: no checkpoints yet
        _run(tmp_path / "d", land, train=_FailingTrainer(land.train, 0))
    with pytest.raises(ValueError, match="no trained checkpoints"):
        ges.routed_evaluator(ges.load_result(str(tmp_path / "d")), land.score)
    with pytest.raises(ValueError, match="router='best'"):
        one_round = _run(tmp_path / "e", land, config=ges.GESConfig(K=3, max_rounds=1))
        ges.routed_evaluator(one_round, land.score, "best")


def test_ges_sampler_is_picklable_clipped_and_physical():
    s = ges.GaussianSampler(np.array([0.02, 0.5]), np.array([0.3, 0.01]), D2_BOX, seed=3)
    s2 = pickle.loads(pickle.dumps(s))
    x = s2(ges.rng_for(16), 5000)
    D2_BOX.validate(x)  # clipped to the box, physical units
    assert np.mean(x[:, 0] == 0.72) > 0.3  # clipping piles mass on the low GCR bound
    np.testing.assert_allclose(x[:, 1].mean(), 0.001 + 0.5 * 0.099, atol=1e-3)
    np.testing.assert_allclose(s2.space.from_unit_scale(s2.sigma), [0.3 * 0.18, 0.01 * 0.099])   # Box: physical sigma


def test_ges_bench_runs():
    t = ges_demo.bench()
    assert set(t) == {"reference_one_gaussian", "coverage_K6", "route_K6"} and all(v > 0 for v in t.values())


DAMAGES = {"truncated": lambda b: b[:len(b) // 2], "random bytes": lambda b: bytes(range(256)) * 4,
           "a JSON list": lambda b: b"[1, 2, 3]", "another format": lambda b: b'{"format": "optuna-v3", "trials": []}',
           "a pickle": lambda b: pickle.dumps({"policy": object})}   # torch would advise weights_only=False


@pytest.mark.parametrize("damage", list(DAMAGES))
def test_ges_damaged_state_names_the_file_and_what_to_do(synthetic_run, tmp_path, damage):
    """A state.json that is truncated, garbage (JSONDecodeError / UnicodeDecodeError) or not a GES state: one
    ValueError naming the file and saying to delete the run_dir, from load_result and from a resumed run_ges."""
    import shutil
    run_dir = tmp_path / "run"
    shutil.copytree(synthetic_run.run_dir, run_dir)
    state = run_dir / ges.STATE_FILE
    state.write_bytes(DAMAGES[damage](state.read_bytes()))
    for call in (lambda: ges.load_result(str(run_dir)), lambda: _run(run_dir)):
        with pytest.raises(ValueError) as e:
            call()
        assert f"{state} is not a readable GES state" in str(e.value) and f"delete {run_dir}" in str(e.value)


@pytest.mark.parametrize("argv, msg", [
    (["demo", "--out", "OUT", "--seed", "-7"], "--seed -7 must be an integer >= 0"),
    (["demo", "--out", "OUT", "--workers", "0"], "--workers 0 must be an integer >= 1"),
    (["demo", "--out", "OUT", "--workers", "-2"], "--workers -2 must be an integer >= 1"),
    (["demo", "--out", " "], "--out needs a folder name"), (["demo", "--out", "/proc/ges_demo_test"], "cannot write"),
    (["demo", "--out", "FILE"], "exists and is not a folder"),
    (["demo", "--out", "OUT", "--K", "0"], "--K 0 must be 'auto' or an integer >= 1"),
    (["demo", "--out", "OUT", "--K", "many"], "--K many must be 'auto' or an integer >= 1"),
    (["demo", "--out", "OUT", "--sites", "0"], "--sites 0 must be an integer >= 1")])
def test_ges_command_line_bad_input_is_one_line_and_writes_nothing(argv, msg, tmp_path, capsys):
    (tmp_path / "file").write_text("a file")
    out = str(tmp_path / "demo")
    assert ges_demo.main([{"OUT": out, "FILE": str(tmp_path / "file")}.get(a, a) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("ges.py: error: ") and msg in err, err
    assert not os.path.exists(out)


# =========================================================================================================
# ges: adaptive K (ges.py section 8) on planted landscapes
# =========================================================================================================
def _adaptive(run_dir, B, K, seed=0, dim=2, train=None, **kw):
    land = ges_demo.planted(B, dim, seed)
    return land, _run(run_dir, land, train=train, config=ges.GESConfig(K=K, adaptive=True, **kw), seed=seed)


def _events(res, kind):
    return [e for h in res.history["rounds"] for e in h.get("events", []) if e["kind"] == kind]


def _region_owners(land, res):
    """Per planted region, the behaviour (argmax logit) of the specialist the router hands most of it to."""
    g = np.linspace(0, 1, 61)
    x = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    region, owner = land.region(x), ges.route_unit(x, res.mu_unit, res.sigma_unit)
    return [int(np.argmax(land.policy(res.ckpt[int(np.argmax(np.bincount(owner[region == b])))])))
            for b in range(len(land.sites))]


def test_ges_adaptive_splits_a_one_specialist_start_on_two_sites(tmp_path):
    land, res = _adaptive(tmp_path, B=2, K=1)
    assert _events(res, "split") and len(res.ckpt) >= 2, [len(h["mu"]) for h in res.history["rounds"]]
    assert _region_owners(land, res) == [0, 1]   # each site's region goes to a specialist of its behaviour
    for h in res.history["rounds"][1:]:          # every round names who trained and who holds each territory
        assert len(h["ids_trained"]) == len(h["wins"]) and len(h["ids"]) == len(h["mu"])
    born = _events(res, "split")[0]
    assert born["child"] == 1 and born["id"] == 0 and "apart" in born["reason"]


def test_ges_adaptive_merges_a_three_specialist_start_on_one_site(tmp_path):
    land, res = _adaptive(tmp_path, B=1, K=3)
    merges = _events(res, "merge")
    assert merges and len(res.ckpt) <= 2, [len(h["mu"]) for h in res.history["rounds"]]
    assert all(e["gap"] <= ges.GESConfig.merge_tol for e in merges)
    K = [len(h["mu"]) for h in res.history["rounds"]]
    assert K[2] < 3, K   # judged once they trained challenge_rounds = 2 rounds (a challenger split off in round
    # 1 is judged with them), then at once


def test_ges_adaptive_keeps_its_bounds_and_resumes_exactly(tmp_path):
    def crash(k, r, *a):
        if r == 3:
            raise RuntimeError("simulated crash")
        return land.train(k, r, *a)
    land, ref = _adaptive(tmp_path / "ref", B=5, K=1, K_max=3)
    assert max(len(h["mu"]) for h in ref.history["rounds"]) == 3 and _events(ref, "split")
    with pytest.raises(RuntimeError, match="simulated crash"):
        _adaptive(tmp_path / "cut", B=5, K=1, K_max=3, train=crash)
    _, resumed = _adaptive(tmp_path / "cut", B=5, K=1, K_max=3)
    assert resumed.history == ref.history and resumed.ids == ref.ids
    np.testing.assert_array_equal(resumed.mu_unit, ref.mu_unit)
    assert [os.path.basename(c) for c in resumed.ckpt] == [os.path.basename(c) for c in ref.ckpt]
    J = ges.routed_evaluator(resumed, land.score)    # the router hands a design to a specialist by its id
    x = resumed.space.sample_uniform(ges.rng_for(3), 50)
    k = resumed.route(x)
    np.testing.assert_allclose(J(x), [land.score(resumed.ids[i], resumed.ckpt[i], x[j:j + 1])[0]
                                      for j, i in enumerate(k)])
    png = figures.plot_territories(resumed.history, str(tmp_path / "t.png"), background=land.region)
    assert os.path.getsize(png) > 20_000


def test_ges_adaptive_refuted_challengers_back_off():
    """A challenger that learned nothing its parent does not know (same scores on its checks) merges back, and
    its parent waits split_cooldown x 2^strikes rounds before its next split; an unrelated merge adds no strike;
    a challenger younger than challenge_rounds is not judged."""
    cfg = ges.GESConfig(adaptive=True)
    S = np.full((3, 3, 4), 0.2)                     # S[i, j]: specialist i on territory j's checks
    S[:2, :2], S[2, 2] = 1.0, 1.0                   # 0 and its challenger 5 alike; 7 its own behaviour
    def terr(r_born, strikes=None):
        return {"ids": [0, 5, 7], "eta": [np.zeros((2, 2))] * 3, "ckpt": ["a", "b", "c"], "wait": {}, "events": [],
                "born": {"0": 0, "5": r_born, "7": 0}, "parent": {"5": 0}, "strikes": strikes or {}}
    out = ges.merge(terr(r_born=4), S, cfg, r=6)    # challenger 5 (born 4) merged into its parent 0
    assert out["ids"] == [0, 7] and out["strikes"] == {"0": 1}
    assert out["wait"] == {"0": 6 + 1 + 2 * cfg.split_cooldown}
    again = ges.merge(terr(r_born=4, strikes={"0": 1}), S, cfg, r=6)
    assert again["strikes"] == {"0": 2} and again["wait"]["0"] == 6 + 1 + 4 * cfg.split_cooldown
    young = ges.merge(terr(r_born=5), S, cfg, r=6)  # one round of training: not judged yet
    assert young["ids"] == [0, 5, 7] and young["strikes"] == {} and young["events"] == []
    other = ges.merge(dict(terr(r_born=4), parent={}), S, cfg, r=6)   # 5 not 0's own: a merge, no strike
    assert other["ids"] == [0, 7] and other["strikes"] == {} and other["wait"] == {"0": 6 + 1 + cfg.split_cooldown}


def test_ges_adaptive_fixed_k_state_is_unchanged(synthetic_run):
    """adaptive=False writes what the fixed-K loop always wrote: no ids, no events, specialists 0..K-1."""
    state = read_json(os.path.join(synthetic_run.run_dir, "state.json"))
    assert not {"ids", "wait", "next_id"} & set(state)
    assert all("events" not in h and "ids" not in h for h in synthetic_run.history["rounds"])
    assert synthetic_run.ids == [0, 1, 2]


@pytest.mark.parametrize("kw, words", [
    (dict(K=5, adaptive=True, K_max=4), "GESConfig.K=5 not allowed: in [K_min, K_max] = [1, 4]"),
    (dict(K_min=3, K_max=2), "GESConfig.K_max=2 not allowed: an integer >= K_min=3"),
    (dict(n_check=1), "GESConfig.n_check=1 not allowed"), (dict(split_gap=0.0), "GESConfig.split_gap=0.0"),
    (dict(merge_tol=1.0), "GESConfig.merge_tol=1.0"), (dict(adaptive="yes"), "GESConfig.adaptive='yes'")])
def test_ges_adaptive_bad_settings_name_the_parameter(kw, words):
    with pytest.raises(ValueError, match=re.escape(words)):
        ges.GESConfig(**kw)


def test_ges_demo_adaptive_ends_with_k_coverage_and_score(tmp_path, capsys):
    assert ges_demo.main(["demo", "--out", str(tmp_path / "d"), "--K", "auto", "--sites", "2", "--seed", "1"]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    m = re.fullmatch(r"final K = (\d+), coverage = ([\d.]+) %, mean score = ([\d.]+)", last)
    assert m and 1 <= int(m[1]) <= 8 and float(m[3]) > 0, last
    assert os.path.getsize(tmp_path / "d" / "territories.png") > 20_000
    assert ges_demo.main(["demo", "--out", str(tmp_path / "f"), "--K", "2", "--sites", "2", "--seed", "1"]) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1].startswith("final K = 2, ")


# ==========================================================================================================
# tpe.py: Tree-structured Parzen Estimator for the outer design search
# ==========================================================================================================



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
def test_tpe_parzen_log_pdf_equals_truncnorm_mixture(multivariate):
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


def test_tpe_parzen_prior_kernel_is_centre_with_range_width():
    p = random_parzen(np.random.default_rng(2), 4, [0.0, -3.0], [1.0, 5.0], False)
    np.testing.assert_array_equal(p.mus[-1], [0.5, 1.0])
    np.testing.assert_array_equal(p.sigmas[-1], [1.0, 8.0])


def test_tpe_parzen_samples_follow_the_mixture():
    """1-D samples pass a KS test against the truncnorm mixture's CDF."""
    rng = np.random.default_rng(3)
    p = random_parzen(rng, 6, [2.0], [5.0], False)
    samples = p.sample(np.random.default_rng(4), 20000)[:, 0]
    assert samples.min() >= 2.0 and samples.max() <= 5.0

    def cdf(x):
        return sum(w * stats.truncnorm.cdf(x, (2.0 - m) / s, (5.0 - m) / s, loc=m, scale=s)
                   for w, m, s in zip(p.weights, p.mus[:, 0], p.sigmas[:, 0]))

    assert stats.kstest(samples, cdf).pvalue > 1e-3


def test_tpe_multivariate_samples_keep_dimensions_together():
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
def test_tpe_gamma_rule():
    cfg = TPEConfig()
    assert [n_good(n, cfg) for n in (1, 10, 11, 100, 101, 250, 1000)] == [1, 1, 2, 10, 11, 25, 25]


def test_tpe_recency_weights():
    cfg = TPEConfig()
    np.testing.assert_array_equal(recency_weights(25, cfg), np.ones(25))
    w = recency_weights(30, cfg)
    np.testing.assert_allclose(w[:5], np.linspace(1 / 30, 1.0, 5))
    np.testing.assert_array_equal(w[5:], np.ones(25))


def test_tpe_neighbour_bandwidths():
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
def test_tpe_same_seed_same_trials(multivariate):
    cfg = TPEConfig(multivariate=multivariate)
    run = lambda seed: optimize(flaky, [0, 0, 0], [1, 1, 1], 30, seed, cfg, verbose=False)
    assert records(run(3)) == records(run(3))
    assert records(run(3)) != records(run(4))


@pytest.mark.parametrize("parallel", [2, 3])
def test_tpe_parallel_startup_trials_equal_the_sequential_study(parallel):
    """run_all's cost stage runs per-design BO's startup trials one per core: the study must not change,
    failed trials (which extend the startup) included."""
    from concurrent.futures import ThreadPoolExecutor
    cfg = TPEConfig(n_startup=7)
    seq = optimize(flaky, [0, 0, 0], [1, 1, 1], 14, 3, cfg, verbose=False)
    with ThreadPoolExecutor(parallel) as ex:
        par = optimize(flaky, [0, 0, 0], [1, 1, 1], 14, 3, cfg, verbose=False, executor=ex, parallel=parallel)
    assert records(par) == records(seq)
    assert sum(not t.ok for t in seq.trials[:9]) >= 1   # a failure fell inside the startup
    with pytest.raises(ValueError, match="parallel=2 needs an executor"):
        optimize(flaky, [0], [1], 3, verbose=False, parallel=2)


class Interrupt(BaseException):
    """Stands in for a crash / Ctrl-C: not an Exception, so it is not a failed trial."""


@pytest.mark.parametrize("stop_after", [4, 17])  # inside and after the random startup
def test_tpe_resumed_optimize_equals_uninterrupted(tmp_path, stop_after):
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
    assert len(read_json(path)["trials"]) == stop_after
    resumed = optimize(flaky, *box, 40, seed=5, path=path, verbose=False)
    assert records(resumed) == records(full)
    assert any(not t.ok for t in full.trials)  # the resume covered failed trials
    assert not list(tmp_path.glob("resumed.json.tmp*"))   # runkit.files.atomic: path.tmp<pid>


def test_tpe_resumed_ask_tell_equals_uninterrupted(tmp_path):
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


def test_tpe_resume_refuses_a_different_study(tmp_path):
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
def test_tpe_bad_bounds_raise(lows, highs, match):
    with pytest.raises(ValueError, match=match):
        TPE(lows, highs)
    with pytest.raises(ValueError, match=match):
        optimize(quadratic, lows, highs, 5, verbose=False)


@pytest.mark.parametrize("n_trials", [0, -3, 2.5, True])
def test_tpe_bad_n_trials_raises(n_trials):
    with pytest.raises(ValueError, match="n_trials"):
        optimize(quadratic, [0], [1], n_trials, verbose=False)


@pytest.mark.parametrize("x", [[0.5], [0.5, 0.5, 0.5], [[0.5, 0.5]], [np.nan, 0.5], [0.5, 1.5]])
def test_tpe_bad_point_raises(x):
    with pytest.raises(ValueError, match="x must"):
        TPE([0, 0], [1, 1]).observe(x, 1.0)


@pytest.mark.parametrize("kwargs,match", [
    (dict(direction="max"), "direction"), (dict(gamma_frac=0.0), "gamma_frac"),
    (dict(n_candidates=0), "n_candidates"), (dict(n_startup=2.0), "n_startup"),
    (dict(prior_weight=-1.0), "prior_weight"), (dict(min_bw_cap=0.5), "min_bw_cap")])
def test_tpe_bad_config_raises(kwargs, match):
    with pytest.raises(ValueError, match=match):
        TPEConfig(**kwargs)


def test_tpe_bad_seed_names_and_y_raise():
    with pytest.raises(ValueError, match="seed"):
        TPE([0], [1], seed=-1)
    with pytest.raises(ValueError, match="names"):
        TPE([0, 0], [1, 1], names=["a"])
    with pytest.raises(ValueError, match="y must"):
        TPE([0], [1]).observe([0.5], "good")


def test_tpe_failing_objective_becomes_failed_trial(tmp_path):
    path = str(tmp_path / "study.json")
    study = optimize(flaky, [0, 0], [1, 1], 40, seed=0, path=path, verbose=False)
    failed = [t for t in study.trials if not t.ok]
    assert len(study.trials) == 40 and failed and len(failed) < 40
    assert {t.error.split(":")[0] for t in failed} <= {"RuntimeError", "non-finite objective value nan"}
    assert study.best.ok and study.best.y == min(t.y for t in study.trials if t.ok)
    saved = read_json(path)["trials"]  # failed trials are kept in the file
    assert [d["y"] is None for d in saved] == [not t.ok for t in study.trials]

    always_fails = optimize(lambda x: 1 / 0, [0], [1], 5, verbose=False)
    assert len(always_fails.trials) == 5 and always_fails.best is None
    # a failed trial must not freeze the search on the same point
    assert len({tuple(t.x) for t in always_fails.trials}) == 5


def test_tpe_failed_trials_are_left_out_of_the_densities():
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
def test_tpe_maximize_mirrors_minimize(multivariate):
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
def test_tpe_suggestions_stay_in_bounds(multivariate):
    lows, highs = [0.5, 0.0, -2.0, 100.0], [1.0, 0.01, 2.0, 101.0]
    study = optimize(lambda x: float(np.sum(x)), lows, highs, 40, 0,
                     TPEConfig(multivariate=multivariate), verbose=False)
    X = np.array([t.x for t in study.trials])
    assert X.shape == (40, 4) and np.all(X >= lows) and np.all(X <= highs)


@pytest.mark.parametrize("damage", list(DAMAGES))
def test_tpe_damaged_study_file_names_the_file_and_what_to_do(tmp_path, damage):
    """A study file that is truncated, garbage (not UTF-8) or of another format: one ValueError naming the file and
    saying to delete it, not a JSON / Unicode / AttributeError traceback."""
    path = tmp_path / "study.json"
    optimize(quadratic, [0, 0], [1, 1], 3, seed=1, path=str(path), verbose=False)
    path.write_bytes(DAMAGES[damage](path.read_bytes()))
    with pytest.raises(ValueError) as e:
        TPE([0, 0], [1, 1], seed=1, path=str(path))
    assert f"{str(path)!r} is not a tpe-study-v1 study file" in str(e.value) and "delete it" in str(e.value)
    assert "\n" not in str(e.value)


def test_tpe_progress_lines_and_callback(capsys):
    seen = []
    optimize(flaky, [0, 0], [1, 1], 5, names=["gcr", "spcf"], verbose=True,
             callback=lambda study, trial: seen.append(trial.index))
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 5 and lines[0].startswith("[tpe] trial 1/5") and "gcr=" in lines[0]
    assert seen == [0, 1, 2, 3, 4]
    optimize(flaky, [0, 0], [1, 1], 5, verbose=False)
    assert capsys.readouterr().out == ""


# ==========================================================================================================
# run_all.py: the smoke pipeline end to end, resume after a kill, bad input, GES's J through the router
# ==========================================================================================================


SMOKE_FIGURES = ["fig1_strip_obstacle.png", "fig1_strip_ramp.png", "fig3_distributions.png",
                 "fig4_expert_contributions.png", "fig5_toe_heights.png", "fig7_k_sensitivity.png",
                 "fig8_design_sensitivity.png"] + [f"fig6_territories_{t}-{s}.png" for t in ("obstacle", "ramp")
                                                   for s in ("d2", "d3")]
TIMING_FIELDS = {"seconds", "stage1_seconds", "stage1_core_s", "bo_measured_s", "bo_s", "ges_stage1_s", "ges_tpe_s",
                 "ges_s", "reduction_pct", "bo_trial_s", "ges_fixed_s", "ges_per_trial_s"}


def _numbers_only(obj):
    """A stage result without its wall times (the only thing a resumed run may change)."""
    if isinstance(obj, dict):
        return {k: _numbers_only(v) for k, v in obj.items() if k not in TIMING_FIELDS}
    if isinstance(obj, list):
        return [_numbers_only(v) for v in obj]
    return obj


def _report_numbers(path):
    """REPORT.md without the lines that hold wall times, rates (steps/s), compute times (core-s) and what follows
    from them (the cost reduction, the break-even trial count), or the commit / code hash (which change when someone
    edits the tree during the test; manifest checks cover them)."""
    lines = read_text(path).splitlines()
    return [ln for ln in lines
            if not re.search(r"wall|steps/s|core-s|reduction|break-even|\b\d+ s\b|git commit", ln, re.I)]


def assert_drawn(png: str) -> None:
    """A figure file is a PNG image with something drawn on it: pixels of more than two colours."""
    import matplotlib.image
    assert read_bytes(png, 8) == b"\x89PNG\r\n\x1a\n", png
    pixels = matplotlib.image.imread(png)
    assert pixels.shape[0] > 100 and len(np.unique(pixels.reshape(-1, pixels.shape[-1]), axis=0)) > 2, png


@pytest.fixture(scope="module")
def smoke_run(tmp_path_factory):
    """One uninterrupted smoke run (1 worker: no process spawns, ~1-2 min here)."""
    out = str(tmp_path_factory.mktemp("smoke") / "a")
    assert run_all.main(["--preset", "smoke", "--out", out, "--workers", "1", "--seed", "3"]) == 0
    return out


@pytest.mark.slow
def test_run_all_smoke_writes_every_table_and_figure(smoke_run):
    rep = read_text(os.path.join(smoke_run, "REPORT.md"))
    for head in ("## Table I", "## Table II", "### Peaks found by TPE", "### Head-to-head", "## Table III",
                 "## K sensitivity", "## Computational cost", "## Figures", "## Wall time per stage"):
        assert head in rep, head
    assert re.search(r"PPO trained at \d+ control steps/s per job in this run \(\d+ training logs", rep)
    assert re.search(r"\| total \| \d+ s = [\d.]+ h \| \d+ s = [\d.]+ h \| [\d.]+ \|", rep)   # beside the plan
    assert "(36.9)" in rep and "(35.2)" in rep and "37 %" in rep          # paper numbers beside ours
    assert "obstacle J by the strict rule" in rep                            # which score the obstacle rows use
    assert re.search(r"\| auto \(ends at \d\) \|", rep)                         # adaptive K's row (ksens_auto)
    assert "nan" not in rep.lower() and " - (" not in rep                # every "ours" cell was measured
    res = read_json(os.path.join(smoke_run, "results.json"))
    assert set(res["stages"]) == set(run_all.STAGES) and all(v is not None for v in res["stages"].values())
    t2 = res["stages"]["table2"]
    for key, cell in t2["cells"].items():
        for m in run_all.METHODS:
            s = np.array(cell[m]["scores"])
            assert len(s) == run_all.SMOKE.n_test and np.isfinite(s).all(), (key, m)
    assert all(np.isfinite(p["peak"]) and p["trials"] == run_all.SMOKE.tpe_trials for p in t2["peaks"].values())
    # numbers that tell runs apart: every score set keeps each episode's final pelvis x, all different (smoke's
    # untrained policies end short of the box, so their one-episode J is one level below the start for all)
    sets = [read_json(f) for f in glob.glob(os.path.join(smoke_run, "scores", "*.json"))]
    final_x = [row for s in sets for row in s["final_x"]]
    assert all(len(row) == run_all.SMOKE.score_episodes for row in final_x)
    assert len({row[0] for row in final_x}) == len(final_x) == sum(len(s["scores"]) for s in sets)
    assert set(res["stages"]["table3"]) == set(run_all.SMOKE.table3_inits)
    assert set(res["stages"]["ksens"]) == {str(k) for k in run_all.SMOKE.ksens_K} | {"auto"}   # ksens_auto
    auto = res["stages"]["ksens"]["auto"]
    assert 1 <= auto["final_K"] <= run_all.SMOKE.ges_auto_K() and len(auto["scores"]) == run_all.SMOKE.n_test
    cost = res["stages"]["cost"]
    assert cost["bo_s"] > 0 and cost["ges_s"] > 0 and np.isfinite(cost["reduction_pct"])
    assert 0.0 <= res["stages"]["figures"]["moe_gate_entropy"] <= 1.0 + 1e-9
    curves = ["e2e_obstacle.png", "e2e_ramp.png", "per_design_bo.png"] + [
        f"ges_{name}.png" for name in os.listdir(os.path.join(smoke_run, "ges"))]   # one per trained policy set
    assert sorted(os.listdir(os.path.join(smoke_run, "figures", "curves"))) == sorted(curves)
    for f in SMOKE_FIGURES + [os.path.join("curves", c) for c in curves]:
        assert_drawn(os.path.join(smoke_run, "figures", f))
    with open(os.path.join(smoke_run, "test_scores.csv")) as fh:
        rows = list(csv_module.DictReader(fh))
    assert len(rows) == 4 * run_all.SMOKE.n_test
    assert all(np.isfinite(float(r[m])) for r in rows for m in run_all.METHODS)
    man = read_json(os.path.join(smoke_run, "manifest.json"))
    assert man["preset"] == "smoke" and man["seed"] == 3
    assert man["budgets"]["ppo_steps"] == run_all.SMOKE.ppo_steps


@pytest.mark.slow
def test_run_all_matched_e2e_mlp_trains_a_specialists_steps(smoke_run):
    """The step-matched e2e MLP of each cell starts from the checkpoint its GES specialists start from and ends
    at the steps one specialist ends at (the warm start's plus Preset.ges_steps of the run's rounds); it is
    scored on the cell's test designs, a Table II column, a head-to-head column and a claim row."""
    res = read_json(os.path.join(smoke_run, "results.json"))["stages"]
    for t in run_all.TASKS:
        for s in run_all.SPACES:
            g = res["ges"][run_all.ges_name(t, s, run_all.SMOKE.K_d2 if s == "d2" else run_all.SMOKE.K_d3,
                                            "fps+lloyd")]
            warm = ppo.load_checkpoint(g["warm_start"]) if g["warm_start"] else None
            mine = ppo.load_checkpoint(os.path.join(smoke_run, "policies", f"mlp_matched-{t}-{s}", "policy.pt"))
            spec = glob.glob(os.path.join(smoke_run, g["run_dir"], "ckpt", f"spec0_round{g['rounds'] - 1:02d}.ckpt"))
            mlp = ppo.load_checkpoint(os.path.join(smoke_run, "policies", f"mlp-{t}-{s}", "policy_best.pt"))
            assert mine["steps"] == res["matched"][f"{t}-{s}"]["steps"]
            assert mine["steps"] == mlp["steps"] + run_all.SMOKE.ges_steps(g["rounds"])
            assert ppo.load_checkpoint(spec[0])["steps"] == (warm["steps"] if warm else 0) + run_all.SMOKE.ges_steps(
                g["rounds"])   # with ges_warm_start (quick, overnight) the two end at the same steps
            assert len(res["matched"][f"{t}-{s}"]["scores"]) == run_all.SMOKE.n_test
    rep = read_text(os.path.join(smoke_run, "REPORT.md"))
    assert "| e2e MLP, step-matched |" in rep and "| vs e2e MLP, step-matched |" in rep
    assert rep.count("GES > the e2e MLP at a specialist's steps") == 4


@pytest.mark.slow
def test_run_all_ges_runs_side_by_side_give_the_inline_numbers(smoke_run, tmp_path, monkeypatch):
    """With a process pool of 2 a stage's GES runs go side by side (ges_runs' threads): a simulated kill in one
    run stops the stage (the others after their round), and the rerun gives exactly the inline run's GES states
    and specialist checkpoints."""
    run = run_all.Run(str(tmp_path), run_all.SMOKE, 3, 2)
    specs = [("obstacle", "d2", 3, "fps+lloyd"), ("obstacle", "d2", 1, "fps+lloyd")]   # Fig. 7's K = 3 and 1
    monkeypatch.setenv("RUN_ALL_FAIL_AT", "ges:obstacle-d2-K3-fps-lloyd:round1")
    with pytest.raises(RuntimeError, match="simulated kill"):
        run_all.ges_runs(run, specs, "GES runs")
    assert read_json(str(tmp_path / "ges" / "obstacle-d2-K3-fps-lloyd" / "state.json"))["round"] == 1
    monkeypatch.delenv("RUN_ALL_FAIL_AT")
    assert list(run_all.ges_runs(run, specs, "GES runs")) == [run_all.ges_name(*sp) for sp in specs]
    mine, ref = raw_numbers(str(tmp_path)), raw_numbers(smoke_run)
    assert sum(k.endswith("state.json") for k in mine) == 2 and len(mine) > 2
    assert [k for k in mine if mine[k] != ref[k]] == []


def test_runkit_and_report_import_nothing_above_them():
    """runkit/ knows nothing of the project outside itself, report/ and codesign/ nothing above the library
    (ballu.py, ppo.py, ges.py, tpe.py): run_all imports them, never the reverse, so a reader can open each module
    on its own."""
    import ast
    here = os.path.dirname(os.path.abspath(__file__))
    top = {os.path.splitext(f)[0] for f in os.listdir(here) if f.endswith(".py")} | {"runkit", "report", "experiments",
                                                                                      "codesign"}
    library = {"runkit", "ballu", "ppo", "ges", "tpe"}
    allowed = {"runkit": {"runkit"}, "report": library | {"report"}, "codesign": library | {"codesign"}}
    for package, ok in allowed.items():
        for f in glob.glob(os.path.join(here, package, "*.py")):
            tree = ast.parse(read_text(f))
            names = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
            names |= {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
            ours = {n.split(".")[0] for n in names} & top
            assert ours <= ok, (f, ours - ok)


def test_runkit_gated_executor_starts_no_job_after_its_time():
    """runkit.pool.GatedExecutor: a job starting before stop_by runs, one starting after raises StopBy (through
    its future, as a pool would); --stop-by HH:MM is its next occurrence within a day, a bad one a BadInput."""
    from runkit.files import BadInput
    from runkit.pool import GatedExecutor, StopBy, stop_time
    ran = []
    ex = GatedExecutor(ges.SerialExecutor(), time.time() + 60)
    assert ex.submit(ran.append, 1).result() is None and ran == [1]
    late = GatedExecutor(ges.SerialExecutor(), time.time() - 1).submit(ran.append, 2)
    with pytest.raises(StopBy, match="no job starts after"):
        late.result()
    assert ran == [1]
    noon = time.mktime((2026, 11, 27, 12, 0, 0, 0, 0, -1))
    assert stop_time("13:30", noon) - noon == 5400 and stop_time("11:00", noon) - noon == 23 * 3600
    with pytest.raises(BadInput, match="--stop-by '7pm' must be a time of day HH:MM"):
        stop_time("7pm")


@pytest.mark.slow
def test_run_all_stopped_by_its_time_and_rerun_equals_uninterrupted(smoke_run, tmp_path, monkeypatch):
    """--stop-by: no job starts after the time (here: after the 6th of the 10 standalone policies), the run stops
    with exit 3 and keeps what finished; the rerun (no stop) gives exactly the uninterrupted run's policies."""
    import types
    from runkit import pool as rpool
    calls = iter(range(10 ** 6))
    clock = types.SimpleNamespace(time=lambda: 0.0 if next(calls) < 6 else 1e12, strftime=time.strftime,
                                  localtime=time.localtime)
    monkeypatch.setattr(rpool, "time", clock)
    monkeypatch.setattr(cli, "stop_time", lambda text: 1.0)
    args = ["--preset", "smoke", "--out", str(tmp_path), "--workers", "1", "--seed", "3",
            "--only", "table1,baselines"]
    assert run_all.main(args + ["--stop-by", "12:00"]) == 3
    assert len(glob.glob(str(tmp_path / "policies" / "*" / "policy.pt"))) == 6
    monkeypatch.undo()
    assert run_all.main(args) == 0
    mine, ref = raw_numbers(str(tmp_path)), raw_numbers(smoke_run)
    assert len(mine) == 2 * 10 and [k for k in mine if mine[k] != ref[k]] == []   # policy.pt, policy_best.pt


@pytest.mark.slow
def test_run_all_bad_input_exits_2_and_overwrites_nothing(smoke_run, tmp_path, capsys):
    base = ["--preset", "smoke", "--workers", "1", "--seed", "3"]
    assert run_all.main(base + ["--out", str(tmp_path / "x"), "--only", "table1,nope"]) == 2
    assert "unknown stage" in capsys.readouterr().err and not (tmp_path / "x").exists()
    blocker = tmp_path / "file"
    blocker.write_text("a file, not a folder")
    assert run_all.main(base + ["--out", str(blocker / "sub")]) == 2
    assert "cannot write" in capsys.readouterr().err
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep me")
    assert run_all.main(base + ["--out", str(foreign), "--fresh"]) == 2
    assert "no manifest.json" in capsys.readouterr().err and (foreign / "notes.txt").read_text() == "keep me"
    before = {f: os.path.getmtime(os.path.join(smoke_run, f)) for f in ("manifest.json", "REPORT.md")}
    for other in (["--preset", "quick"], ["--seed", "4"]):   # a folder of another preset / seed
        assert run_all.main(base + ["--out", smoke_run] + other) == 2
        assert "--fresh" in capsys.readouterr().err
    assert before == {f: os.path.getmtime(os.path.join(smoke_run, f)) for f in before}
    assert run_all.main(base + ["--out", str(tmp_path / "y"), "--only", "table2"]) == 2   # inputs missing
    assert "needs stage(s)" in capsys.readouterr().err and not (tmp_path / "y").exists()
    with pytest.raises(SystemExit) as e:                     # argparse: unknown preset
        run_all.main(["--preset", "huge"])
    assert e.value.code == 2
    proc = subprocess.run([sys.executable, "run_all.py", "--only", "figures,nope", "--out", str(tmp_path / "z")],
                          cwd=os.path.dirname(os.path.abspath(run_all.__file__)), capture_output=True, text=True)
    assert proc.returncode == 2 and "unknown stage" in proc.stderr


def test_run_all_probe_tiebreak_orders_only_ties():
    """Preset.probe_tiebreak: J plus 1e-3 x the mean final x (clipped, a blow-up as -10 m) orders probes tied on
    whole levels by how far the robot went, and never reorders two different levels (least step 0.39 deg)."""
    full = np.array([[0.45, 0.45, 0.8, 0.01], [0.45, 0.45, 0.85, 0.02], [0.45, 0.45, 0.9, 0.03]])
    trace = {full[0].tobytes(): [1.0, 2.0], full[1].tobytes(): [0.5, None], full[2].tobytes(): [50.0, 60.0]}
    np.testing.assert_allclose(policies.tiebreak(full, trace), [1.5e-3, -4.75e-3, 1e-2])
    steps = np.diff(ballu.level_score("ramp", np.arange(ballu.MAX_LEVEL + 1)))
    assert 2 * np.abs(policies.tiebreak(full, trace)).max() < steps.min()
    assert not run_all.OVERNIGHT.probe_tiebreak and not run_all.Preset.ges_final_train   # levers: off by default
    assert run_all.OVERNIGHT.ges_final_train   # adopted (docs/ges_schedule)


def test_run_all_recorded_preset_is_the_preset_a_run_ran_with():
    """A committed run's manifest gives the budgets it ran with; a field added since is the class's default (the
    behaviour before it), not today's preset value: the oldest overnight run trained no final round, and its round 0
    trained ges_round_steps (before ges_first_round_steps)."""
    here = os.path.dirname(os.path.abspath(__file__))
    man = lambda p: json.load(open(os.path.join(here, p, "results.json")))["manifest"]   # noqa: E731
    for seed in ("seed0", "seed1"):   # both reruns on today's schedule, scored by the facts' rule (before strict)
        rec = run_all.recorded_preset(man(f"docs/overnight/{seed}"))
        assert rec == replace(run_all.OVERNIGHT, score_strict=False) and run_all.OVERNIGHT.score_strict, seed
    old = run_all.recorded_preset(man("docs/archive/paper_obs/overnight"))
    assert old.ges_first_round_steps is None and not old.ges_final_train
    assert run_all.recorded_preset({"preset": "quick"}) == run_all.QUICK   # no budgets recorded: the preset's


def test_run_all_set_overrides_a_budget_kept_and_checked_by_name(tmp_path, capsys, monkeypatch):
    """--set FIELD=VALUE changes the preset (typed by the field), the plan and the manifest; a rerun with another
    value is refused naming the budget; a bad field or value is a one-line error that writes nothing."""
    out, base = str(tmp_path / "r"), ["--preset", "smoke", "--workers", "1", "--only", "table1"]
    assert run_all.main(base + ["--out", out, "--set", "n_test=2", "--set", "ksens_K=1,2,3",
                                "--set", "probe_level_steps=none", "--set", "ges_target_coverage=0.5"]) == 0
    man = json.load(open(os.path.join(out, "manifest.json")))
    assert man["budgets"]["n_test"] == 2 and man["budgets"]["ksens_K"] == [1, 2, 3]
    assert man["overrides"] == {"n_test": 2, "ksens_K": [1, 2, 3], "probe_level_steps": None,
                                "ges_target_coverage": 0.5}   # a fraction (was refused as < 1)
    assert "n_test=2" in open(os.path.join(out, "REPORT.md")).read()
    capsys.readouterr()
    assert run_all.main(base + ["--out", out, "--set", "n_test=3"]) == 2
    assert "budget n_test (2 there, 3 now)" in capsys.readouterr().err
    del man["budgets"]["probe_tiebreak"]   # a folder made before the field: it ran with the class default (off)
    json.dump(man, open(os.path.join(out, "manifest.json"), "w"))
    keep = base + ["--out", out, "--set", "n_test=2", "--set", "ksens_K=1,2,3", "--set", "probe_level_steps=none",
                   "--set", "ges_target_coverage=0.5"]
    assert run_all.main(keep + ["--set", "probe_tiebreak=true"]) == 2
    assert "budget probe_tiebreak (False there, True now)" in capsys.readouterr().err
    assert run_all.main(keep) == 0
    for bad, words in (("nope=1", "FIELD one of"), ("n_test=abc", "not a value of type int"),
                       ("n_test=0", "must be >= 1"), ("ges_warm_start=maybe", "type bool"),
                       ("ges_target_coverage=1.5", "must be in [0, 1]")):
        assert run_all.main(base + ["--out", str(tmp_path / "bad"), "--set", bad]) == 2
        assert words in capsys.readouterr().err and not (tmp_path / "bad").exists()
    monkeypatch.setattr(cli, "calibrate", lambda job, ex, workers, batch: ex.shutdown() or {
        "workers": workers, "jobs": ["mlp obstacle"] * workers, "train_rate": 400.0, "score_rate": 300.0,
        "seconds": 1.0, "time": "now", "cpu": "test CPU", "batch": list(batch)})
    plans = []
    for steps in ("380000", "760000"):
        assert run_all.main(["--preset", "quick", "--plan", "--set", f"ppo_steps={steps}", "--workers", "2",
                             "--out", str(tmp_path / "p")]) == 0
        plans.append(float(re.search(r"total +([\d.]+) h", capsys.readouterr().out).group(1)))
    assert plans[1] > plans[0]


@pytest.mark.slow
def test_run_all_cells_run_alone_with_the_full_runs_numbers(smoke_run, tmp_path, capsys):
    """--set cells=ramp-d2 runs that cell alone (its baseline-design policy, e2e policies, GES, step-matched MLP,
    Table II row, figures; no Table III, Fig. 7 or cost, whose cells it leaves out), and every number it makes is
    the full run's: seeds derive from names, never from what else runs. Its plan is smaller."""
    out = str(tmp_path / "one")
    assert run_all.main(["--preset", "smoke", "--out", out, "--workers", "1", "--seed", "3",
                         "--set", "cells=ramp-d2"]) == 0
    mine, full = raw_numbers(out), raw_numbers(smoke_run)
    assert sorted(os.listdir(os.path.join(out, "policies"))) == ["baseline-ramp", "mlp-ramp-d2", "mlp_matched-ramp-d2",
                                                                  "moe-ramp-d2"]
    assert os.listdir(os.path.join(out, "ges")) == ["ramp-d2-K3-fps-lloyd"]
    assert mine and [k for k in mine if mine[k] != full.get(k)] == []
    res = read_json(os.path.join(out, "results.json"))["stages"]
    assert list(res["table2"]["cells"]) == ["ramp-d2"] and res["table3"] == res["ksens"] == res["cost"] == {}
    rep = read_text(os.path.join(out, "REPORT.md"))
    assert "| ramp | D2 |" in rep and "| obstacle | D2 |" not in rep and "## Table III" not in rep
    assert "(`--set`): cells=ramp-d2" in rep
    hours = []
    for cells in ([], ["--set", "cells=ramp-d2"]):
        assert run_all.main(["--preset", "smoke", "--plan", "--workers", "1", "--out", str(tmp_path / "p")] + cells) == 0
        hours.append(float(re.search(r"total .* = ([\d.]+) min", capsys.readouterr().out).group(1)))
    assert hours[1] < hours[0]


@pytest.mark.slow
def test_run_all_ges_score_is_the_density_router(smoke_run):
    """GES's J in the pipeline: each design is routed like GESResult.route (paper eq. 10) and played by that
    specialist alone."""
    run_dir = os.path.join(smoke_run, "ges", "obstacle-d3-K6-fps-lloyd")
    res, preset = ges.load_result(run_dir), run_all.PRESETS["smoke"]
    space = policies.space_of(preset, "obstacle", "d3")
    theta = space.sample_uniform(np.random.default_rng(0), 64)
    ks = res.route(theta)
    np.testing.assert_array_equal(ges.route_unit(res.space.to_unit(theta), res.mu_unit, res.sigma_unit), ks)
    pick = np.concatenate([np.flatnonzero(ks == k)[:1] for k in np.unique(ks)])[:3]   # one design per specialist
    J = policies.ges_J(run_dir, "obstacle", space, preset)(theta[pick])
    best = [ppo.scored_path(c) for c in res.ckpt]   # the preset's rule: each specialist's best policy
    alone = [ballu.score(ppo.load_policy(best[ks[i]]), space.full(theta[i]), "obstacle",
                         episodes=preset.score_episodes, start_level=preset.score_start_level)[0] for i in pick]
    np.testing.assert_array_equal(J, alone)
    obs = np.random.default_rng(2).normal(size=(5, ballu.OBS_DIM)).astype(np.float32)
    np.testing.assert_array_equal(policies.ges_specialist(run_dir, theta[pick[0]], preset)(obs),   # Figs. 1, 5
                                  ppo.load_policy(best[ks[pick[0]]])(obs))


def test_runkit_uncertainty_against_independent_references():
    """The bootstrap CI of a mean matches the normal-theory CI for a large sample and scipy.stats.bootstrap's
    percentile CI (the same resamples) to round-off; the paired comparison's p-value is scipy's Wilcoxon; a
    planted improvement is 'supported', its mirror 'not supported', noise and all-ties 'not resolved'."""
    rng = np.random.default_rng(0)
    x = rng.normal(10, 3, 400)
    half = 1.96 * x.std(ddof=1) / math.sqrt(len(x))
    np.testing.assert_allclose(rstats.bootstrap_ci(x), (x.mean() - half, x.mean() + half), atol=0.05 * half)
    ref = stats.bootstrap((x,), np.mean, n_resamples=rstats.N_BOOT, method="percentile",
                          rng=np.random.default_rng(0)).confidence_interval
    np.testing.assert_allclose(rstats.bootstrap_ci(x), (ref.low, ref.high), rtol=1e-12)
    a = x + rng.normal(0.5, 1.0, len(x))
    cmp = rstats.paired_comparison(a, x)
    assert cmp["p"] == pytest.approx(stats.wilcoxon(a, x).pvalue) and cmp["diff_lo"] < 0.5 < cmp["diff_hi"]
    assert cmp["win_pct"] == pytest.approx(100 * np.mean(a > x)) and cmp["win_lo"] < cmp["win_pct"] < cmp["win_hi"]
    assert rstats.verdict(cmp) == "supported" and rstats.verdict(rstats.paired_comparison(x, a)) == "not supported"
    assert rstats.verdict(rstats.paired_comparison(x + rng.normal(0, 1, len(x)), x)) == "not resolved"
    same = rstats.paired_comparison(x, x)
    assert same["p"] == 1.0 and same["tie_pct"] == 100 and rstats.verdict(same) == "not resolved"
    assert rstats.wins(np.array([3, 2, 1, 1]), np.array([1, 2, 3, 1])) == {"win_pct": 25.0, "tie_pct": 50.0}


def test_report_best_of_needs_every_comparison():
    """A claim 'X is best' is supported when X beats every other, not supported when some other beats X."""
    rng = np.random.default_rng(0)
    x = rng.normal(10, 3, 400)
    a = x + rng.normal(0.5, 1.0, len(x))
    table = {"a": {"scores": a.tolist()}, "b": {"scores": x.tolist()}}
    assert tables.best_of(table, "a") == "supported" and tables.best_of(table, "b") == "not supported"
    table["c"] = {"scores": (a + rng.normal(0, 1, len(x))).tolist()}   # a rival a does not beat
    assert tables.best_of(table, "a") == "not resolved" and tables.best_of(table, "d") == "not measured"


def test_report_cross_seed_claims_hold_only_where_every_run_agrees(tmp_path):
    """report.cross_seed: a claim holds across runs only if every run supports it. Two runs with GES 3 cm above
    every baseline: 'holds in both'; the second run's GES 3 cm below instead: 'conflicting'; a damaged results
    file: a one-line error, not a traceback."""
    from report import cross_seed
    rng = np.random.default_rng(0)

    def run(folder, ges_shift):
        cells = {}
        for t, s in tables.CELLS:
            x = rng.normal(20, 4, 60)
            shifts = {"baseline": 0.0, "mlp": 0.0, "moe": 0.0, "ges": ges_shift}
            cells[f"{t}-{s}"] = {m: {"scores": (x + d + rng.normal(0, 0.5, 60)).tolist()} for m, d in shifts.items()}
        os.makedirs(folder)
        with open(os.path.join(folder, "results.json"), "w") as fh:
            ges_d2 = {"scores": cells["obstacle-d2"]["ges"]["scores"]}
            json.dump({"manifest": {"preset": "quick", "seed": len(os.listdir(tmp_path))},
                       "stages": {"table2": {"cells": cells}, "ksens": {"1": ges_d2, "3": ges_d2}}}, fh)
        return str(folder)

    a, b, c = run(tmp_path / "a", 3.0), run(tmp_path / "b", 3.0), run(tmp_path / "c", -3.0)
    rows = [line for line in cross_seed.report([a, b]).splitlines() if line.startswith("| GES >")]
    assert len(rows) == 8 and all(line.endswith("| holds in both |") for line in rows)
    text = cross_seed.report([a, c])
    assert "GES > e2e MLP supported in 0 of 4 cells, reversed in 4" in text
    assert text.count("conflicting (supported in 1, reversed in 1 of 2)") == 8 + 1   # 8 cells + K = 1 > e2e MLP
    assert "| K = 1 > K = 3, obstacle D2 (ours: Fig. 7) | not resolved (+0.0" in text   # the same scores: a tie
    assert cross_seed.across(["supported", "not resolved", "not measured"]) == (
        "supported in 1 of 2, unresolved in the rest; not measured in 1")
    with open(os.path.join(c, "results.json"), "w") as fh:
        fh.write("{")
    with pytest.raises(SystemExit, match="not a run_all results file"):
        cross_seed.report([a, c])



def test_report_splits_ges_gap_by_territory(tmp_path):
    """territory_split: GES - e2e MLP (and each side's mean J) over the test designs inside GES's final territories
    (max_k f_k > e^-2, the 2-sigma contour) and outside, per cell. One territory at gcr 0.8 +- 0.01, spcf 0.05 +-
    0.01: designs 1 and 1.9 sigma away are inside, 2.1 sigma away outside; a D3 design's l is read from l_f.
    REPORT.md's section and report.cross_seed's table say why in a line where GES > e2e MLP is not supported."""
    from report import cross_seed
    from report.tables import report_territories, territory_split
    folder = tmp_path / "run"
    folder.mkdir()
    ges_runs = {"obstacle-d2-K1-fps-lloyd": {"names": ["gcr", "spcf"], "mu": [[0.8, 0.05]], "sigma": [[0.01, 0.01]],
                                             "coverage": 0.25},
                "ramp-d3-K1-fps-lloyd": {"names": ["gcr", "spcf", "l"], "mu": [[0.8, 0.05, 0.3]],
                                         "sigma": [[0.01, 0.01, 0.01]], "coverage": 0.5}}
    rows = [("obstacle", "d2", 0.45, 0.81, 0.05, 10, 13), ("obstacle", "d2", 0.45, 0.8, 0.069, 10, 11),
            ("obstacle", "d2", 0.45, 0.8, 0.071, 10, 4), ("ramp", "d3", 0.321, 0.8, 0.05, 20, 20),
            ("ramp", "d3", 0.3, 0.8, 0.05, 20, 25)]
    with open(folder / "test_scores.csv", "w", newline="") as fh:
        w = csv_module.writer(fh)
        w.writerow(["task", "space", "l_f", "l_t", "gcr", "spcf", "baseline", "mlp", "moe", "ges"])
        w.writerows([[t, s, l, l, g, p, 0, m, 0, j] for t, s, l, g, p, m, j in rows])
    cells = {f"{t}-{s}": {m: {"scores": [r[5 if m == "mlp" else 6] for r in rows if r[:2] == (t, s)]}
                          for m in ("baseline", "mlp", "moe", "ges")} for t, s in (("obstacle", "d2"), ("ramp", "d3"))}
    run = {"stages": {"table2": {"cells": cells}, "ges": ges_runs}}
    split = territory_split(run["stages"], str(folder))
    assert split == {"obstacle-d2": [(2.0, 2, 12.0, 10.0), (-6.0, 1, 4.0, 10.0)],
                     "ramp-d3": [(5.0, 1, 25.0, 20.0), (0.0, 1, 20.0, 20.0)]}
    assert territory_split(run["stages"], str(tmp_path)) == {}   # no test_scores.csv
    section = "\n".join(report_territories(run["stages"], str(folder)))
    assert "| obstacle D2 | not resolved | 25.0% | 12.0 / 10.0 (+2.0, 2) | 4.0 / 10.0 (-6.0, 1) |" in section
    assert ("- obstacle D2 (not resolved): on their own designs (2 of the test designs, inside the territories) the "
            "specialists score 12.0 against the e2e MLP's 10.0 (+2.0); outside them (1 of the test designs, 75% of "
            "the space uncovered) specialists trained elsewhere score 4.0 against 10.0 (-6.0).") in section
    table = cross_seed.split_table([run], ["seed 0"], [str(folder)])
    assert "| obstacle D2 | +2.0 (2) / -6.0 (1) |" in table and "| ramp D2 | - |" in table
    assert any(line.startswith("- seed 0, ramp D3 (not resolved): on their own designs (1 of the") for line in table)


def raw_numbers(out: str) -> dict:
    """Every raw number of a run: score sets (J and every episode's final pelvis x), GES states (coverage,
    territories, probes, winners per round), TPE trials (x, y), and a hash of every policy checkpoint's weights
    (the standalone policies' policy.pt and every GES specialist's round checkpoints)."""
    nums = {}
    for f in sorted(glob.glob(os.path.join(out, "scores", "*.json"))):
        nums[os.path.relpath(f, out)] = {k: read_json(f)[k] for k in ("scores", "final_x")}
    for f in sorted(glob.glob(os.path.join(out, "ges", "*", "state.json"))):
        nums[os.path.relpath(f, out)] = [{k: h[k] for k in ("coverage", "mu", "sigma", "probes_unit", "winner")}
                                         for h in read_json(f)["history"]]
    for f in sorted(glob.glob(os.path.join(out, "tpe", "*.json"))):
        nums[os.path.relpath(f, out)] = [(t["x"], t["y"]) for t in read_json(f)["trials"]]
    for f in sorted(glob.glob(os.path.join(out, "**", "*.pt"), recursive=True)
                    + glob.glob(os.path.join(out, "ges", "*", "ckpt", "*.ckpt"))):
        weights = torch.load(f, weights_only=False)["policy"]
        nums[os.path.relpath(f, out)] = hashlib.sha1(b"".join(v.numpy().tobytes() for v in weights.values())).hexdigest()
    return nums


def _wait_for_port(port: int, seconds: float = 60) -> None:
    import socket
    import time
    deadline = time.time() + seconds
    while time.time() < deadline:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.3)
    raise TimeoutError(f"nothing listens on port {port} after {seconds} s")


@contextlib.contextmanager
def dask_cluster_by_hand(folder, workers: int = 2, **env_extra):
    """The README's cluster commands as a user types them: `dask scheduler` and `dask worker ADDR --nthreads 1
    --nworkers N` started in `folder` (not the checkout) without PYTHONPATH (nothing of ours importable there),
    the workers' environment plus `env_extra`; yields the scheduler's address, then ends both."""
    import signal
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    dask = [sys.executable, "-m", "dask"]
    log = open(os.path.join(folder, "cluster.log"), "w")
    procs = [subprocess.Popen(dask + ["scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
                              cwd=folder, env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)]
    try:
        _wait_for_port(port)
        procs.append(subprocess.Popen(dask + ["worker", f"tcp://127.0.0.1:{port}", "--nthreads", "1", "--nworkers",
                                              str(workers), "--no-dashboard"], cwd=folder, env={**env, **env_extra},
                                      stdout=log, stderr=subprocess.STDOUT, start_new_session=True))
        yield f"tcp://127.0.0.1:{port}"
    finally:
        for p in reversed(procs):   # each in its own session: end the worker's nanny processes with it
            os.killpg(p.pid, signal.SIGTERM)
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
        log.close()


@pytest.mark.slow
def test_run_all_killed_on_a_dask_cluster_started_by_hand_and_rerun_equals_uninterrupted(smoke_run, tmp_path,
                                                                                         monkeypatch):
    """On a Dask cluster of 2 workers started by hand (dask_cluster_by_hand: the client uploads the modules),
    `--executor dask --scheduler ADDR` killed twice and rerun gives exactly the raw numbers of the inline 1-worker
    run with the same seed: every score, GES territory, TPE trial and policy checkpoint, and the REPORT's numbers.
    One kill comes mid GES run (a hook in the client: RUN_ALL_FAIL_AT), one mid TPE search (a hook where the
    search runs: the workers carry RUN_ALL_FAIL_AT from their start; the rerun's search resumes past that trial,
    so it fires once). One test for executors, worker counts and resumes: a smoke run costs minutes."""
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    out = str(tmp_path / "b")
    with dask_cluster_by_hand(str(elsewhere), RUN_ALL_FAIL_AT="tpe:obstacle-d2-ges:trial1") as address:
        args = ["--preset", "smoke", "--out", out, "--workers", "2", "--seed", "3", "--executor", "dask",
                "--scheduler", address]
        assert run_all.main(args + ["--only", "table1,baselines"]) == 0
        monkeypatch.setenv("RUN_ALL_FAIL_AT", "ges:obstacle-d3-K6-fps-lloyd:round1")   # mid GES run
        with pytest.raises(RuntimeError, match="simulated kill at ges"):
            run_all.main(args)
        monkeypatch.delenv("RUN_ALL_FAIL_AT")
        with pytest.raises(RuntimeError, match="simulated kill at tpe"):               # mid TPE search
            run_all.main(args)
        assert run_all.main(args) == 0
    a, b = (read_json(os.path.join(d, "results.json"))["stages"] for d in (smoke_run, out))
    assert _numbers_only(a) == _numbers_only(b)
    mine, ref = raw_numbers(out), raw_numbers(smoke_run)   # every J and final x, GES state, TPE trial, policy
    assert mine.keys() == ref.keys() and len(ref) >= 100   # 111 in the smoke preset
    assert [k for k in ref if mine[k] != ref[k]] == []
    assert _report_numbers(os.path.join(smoke_run, "REPORT.md")) == _report_numbers(os.path.join(out,
                                                                                                "REPORT.md"))
    # the killed GES run repeated its interrupted round and continued the specialists' PPO step counts
    ck = os.path.join(out, "ges", "obstacle-d3-K6-fps-lloyd", "ckpt")
    for r in range(run_all.SMOKE.ges_max_rounds):
        steps = ppo.load_checkpoint(os.path.join(ck, f"spec0_round{r:02d}.ckpt"))["steps"]
        batch = run_all.SMOKE.ppo_envs * run_all.SMOKE.ppo_rollout
        assert steps >= (r + 1) * run_all.SMOKE.ges_round_steps > steps - batch


@pytest.mark.slow
def test_run_all_local_dask_cluster_runs_jobs():
    """`--executor dask` without --scheduler: a local cluster of --workers processes runs run_all's jobs (the
    numbers' equality is the hand-started cluster's test above)."""
    ex = run_all.Run("unused", run_all.SMOKE, 0, 2, "dask").pool()
    try:
        assert ex.submit(policies.derive_seed, 3, "ppo", "a").result() == policies.derive_seed(3, "ppo", "a")
    finally:
        ex.shutdown(wait=True)
        pool.close_dask_clients()


@pytest.mark.parametrize("address, words", [("notanaddress", "missing port number"),
                                             ("tcp://127.0.0.1:1", "Timed out trying to connect")])
def test_run_all_bad_scheduler_is_one_line_within_seconds(address, words, tmp_path, capsys):
    import time
    t0 = time.time()
    assert run_all.main(["--preset", "smoke", "--out", str(tmp_path / "x"), "--executor", "dask",
                         "--scheduler", address]) == 2
    err = capsys.readouterr().err
    assert time.time() - t0 < pool.CONNECT_TIMEOUT_S + 5 and not (tmp_path / "x").exists()
    assert err.count("\n") == 1 and f"error: --scheduler {address}: no Dask scheduler reachable" in err
    assert words in err


def test_run_all_scheduler_needs_the_dask_executor(tmp_path, capsys):
    assert run_all.main(["--preset", "smoke", "--out", str(tmp_path / "x"), "--scheduler", "tcp://h:8786"]) == 2
    assert "--scheduler tcp://h:8786 needs --executor dask" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_report_level_of_inverts_the_score_and_cells_read_ours_then_paper():
    for task in ("obstacle", "ramp"):
        for lv in range(ballu.MAX_LEVEL + 1):
            assert figures.level_of(task, float(ballu.level_score(task, lv))) == lv
    assert tables.cell(12.345, None) == "12.3 (-)" and tables.cell(None, 36.9) == "- (36.9)"


def test_run_all_derived_seeds_are_pinned():
    """Another derivation (e.g. Python's salted hash()) would change every run's numbers."""
    seed = policies.derive_seed
    assert (seed(0, "ppo", "a"), seed(1, "ppo", "a"), seed(0, "a"), seed(0, "b")) == (
        1460073160, 529933479, 450999037, 1911616833)


def specialist_budget_fits(p) -> bool:
    """The presets' rule for a GES specialist's steps, as the authors ran GES [facts: docs/facts.md section 9]:
    round 0 trains a per-design policy's budget, 1,600 updates against the universal policy's 1,500, and each
    later round less, 500. So round 0 gets at most one policy's ppo_steps x 1600 / 1500 and a later round at
    most round 0's. It replaces 'a specialist's total at the round cap <= ppo_steps', which an overnight preset
    may break on purpose (the night's steps buy most in the specialists, docs/presets.md) and which the authors'
    7.4x longer specialists broke too."""
    return p.ges_steps(1) <= p.ppo_steps * 1600 / 1500 and p.ges_round_steps <= p.ges_steps(1)


def test_run_all_presets_keep_their_budget_rules():
    for p in run_all.PRESETS.values():
        assert specialist_budget_fits(p) and p.cost_trials <= p.tpe_trials, p.name
        ballu.check_level_steps(p.probe_level_steps, None)   # a valid probe schedule, or None
        assert p.score_start_level is None or 0 <= p.score_start_level <= ballu.MAX_LEVEL
    assert run_all.PAPER.probe_level_steps is None and run_all.PAPER.score_start_level is None   # the paper's J
    night = run_all.OVERNIGHT
    assert night.ges_steps(night.ges_max_rounds) == 800_000   # 600k in round 0, then 100k in each of 2 rounds
    for outgrown in (replace(night, ges_first_round_steps=1_100_000),            # round 0 above one policy's
                     replace(run_all.QUICK, ges_round_steps=300_000),             # a later round above round 0
                     replace(run_all.PAPER, ges_round_steps=22_000_000)):         # round 0 (no own size) too
        assert not specialist_budget_fits(outgrown)


class Grab(Exception):
    """Carries what a monkeypatched function was called with out of the code under test."""


def test_run_all_probe_schedule_scores_ges_probes_only(monkeypatch, tmp_path):
    """The preset's probe schedule reaches ballu.score only through GES's probe score_fn; the router's J (test
    designs, TPE) and single policies keep the paper's episodes and the preset's start level."""
    seen = []

    def fake_score(policy, designs, task, **kw):
        seen.append(kw)
        return np.zeros(len(designs)), np.zeros((len(designs), 1))

    monkeypatch.setattr(ballu, "score", fake_score)
    monkeypatch.setattr(ppo, "load_policy", lambda ckpt: ballu.stand)
    p = replace(run_all.QUICK, probe_level_steps=probe_agreement.BISECTION, score_start_level=3)
    space = policies.space_of(p, "obstacle", "d2")
    theta = space.sample_uniform(np.random.default_rng(0), 2)
    policies.ScoreSpecialist("obstacle", space, p, probe=True)(0, "ckpt", theta)
    policies.ScoreSpecialist("obstacle", space, p)(0, "ckpt", theta)
    trace = {}
    policies.PolicyJ(ballu.stand, space, "obstacle", p, trace=trace)(theta)
    assert [(s["level_steps"], s["episodes"], s["start_level"]) for s in seen] == [
        (probe_agreement.BISECTION, None, 3), (None, 20, 3), (None, 20, 3)]
    assert list(trace.values()) == [[0.0], [0.0]] and list(trace) == [d.tobytes() for d in space.full(theta)]

    def grab(space, train_fn, score_fn, *args, **kw):
        raise Grab(score_fn)

    monkeypatch.setattr(ges, "run_ges", grab)
    with pytest.raises(Grab) as e:
        run_all.ges_run(run_all.Run(str(tmp_path), p, 0, 1), "obstacle", "d2", 3, "fps+lloyd", None)
    assert e.value.args[0].probe


@pytest.mark.slow
def test_experiments_probe_agreement_runs_on_a_tiny_size(smoke_run, capsys):
    """The probe-agreement measurement on 2 designs x 2 smoke policies, 2 episodes against a one-episode
    schedule: it prints the same-winner share, rank correlation and both wall times, and with --jitter the
    ceiling (J against itself on moved designs). Bad input exits 2 naming the argument."""
    ckpts = ",".join(os.path.join(smoke_run, "policies", f"{m}-obstacle-d2", "policy.pt") for m in ("mlp", "moe"))
    assert probe_agreement.main([ckpts, "--designs", "2", "--episodes", "2", "--level-steps", "2",
                                 "--workers", "1", "--jitter", "0.01"]) == 0
    out = capsys.readouterr().out
    for text in ("2 uniform D2 designs x 2 checkpoints", "same winner", "Spearman", "wall time: full J",
                 "the bar (PROBE_BAR)", "ceiling: the full J on designs moved by +-1 %"):
        assert text in out, text
    for argv, msg in (([ckpts.split(",")[0]], ">= 2 existing checkpoints"),
                      ([ckpts, "--level-steps", "0,2"], "--level-steps 0,2 must be"),
                      ([ckpts, "--task", "stairs"], "--task stairs must be one of"),
                      ([ckpts, "--designs", "0"], "--designs 0"),
                      ([ckpts, "--jitter", "1.5"], "--jitter 1.5 must lie in [0, 1)")):
        assert probe_agreement.main(argv) == 2
        assert msg in capsys.readouterr().err, msg


_ORPHAN_PARENT = """
import os, sys, time
import run_all
ex = run_all.Run(sys.argv[1], run_all.SMOKE, 0, 2).pool()
pids = sorted({f.result() for f in [ex.submit(os.getpid) for _ in range(8)]})
busy = [ex.submit(time.sleep, 300) for _ in range(2)]   # in-flight jobs, as a killed stage leaves them
print(*pids, flush=True)
time.sleep(300)
"""


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"   # a zombie has exited
    except FileNotFoundError:
        return False


@pytest.mark.slow
def test_run_all_pool_workers_exit_when_the_run_is_killed(tmp_path):
    """A run_all killed with SIGKILL must not leave its process-pool workers running their in-flight jobs
    (runkit.pool.exit_with_parent): both workers are gone within a few seconds of the kill."""
    import signal
    import time
    parent = subprocess.Popen([sys.executable, "-c", _ORPHAN_PARENT, str(tmp_path)], cwd=os.path.dirname(
        os.path.abspath(__file__)), stdout=subprocess.PIPE, text=True)
    try:
        pids = [int(p) for p in parent.stdout.readline().split()]
        assert len(pids) >= 1 and all(_alive(p) for p in pids), pids
        time.sleep(1.0)                                    # the sleeps are now running in the workers
    finally:
        parent.send_signal(signal.SIGKILL)
        parent.wait()
    deadline = time.time() + 15
    while any(_alive(p) for p in pids) and time.time() < deadline:
        time.sleep(0.2)
    assert not any(_alive(p) for p in pids), [p for p in pids if _alive(p)]


_CLOCKED_STAGE = """
import sys, time
from runkit.clock import StageClock
clock = StageClock(sys.argv[1], "baselines", every=0.05)
print("ticking", flush=True)
time.sleep(60)
"""


def test_runkit_stage_time_survives_sigkill(tmp_path):
    """A stage's wall time reaches stage_seconds.json while it runs (runkit.clock.StageClock), so an attempt killed by
    SIGKILL, which runs no `finally`, still counts, added to the earlier attempts' time; close() writes the rest."""
    import signal
    path = str(tmp_path / "stage_seconds.json")
    run_all.write_json(path, {"table1": 1.0, "baselines": 100.0})   # an earlier attempt's 100 s
    child = subprocess.Popen([sys.executable, "-c", _CLOCKED_STAGE, path], cwd=os.path.dirname(
        os.path.abspath(__file__)), stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "ticking"
        t0 = time.time()
        time.sleep(1.0)
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait()
    lived = time.time() - t0
    times = run_all.read_json(path)
    assert times["table1"] == 1.0 and 100.0 + lived - 0.5 <= times["baselines"] <= 100.0 + lived + 0.5, (lived, times)
    clock = StageClock(path, "baselines", every=60)   # the next attempt starts from what the killed one left
    time.sleep(0.2)
    assert 0.2 <= clock.close() < 1.0
    assert abs(run_all.read_json(path)["baselines"] - times["baselines"] - 0.2) < 0.2


def test_runkit_eta_of_a_resumed_run():
    """A resumed run's ETA counts what earlier attempts spent on a stage left: baselines planned 1000 s with 840 s
    spent -> 160 s of it left, not 1000; never below 0."""
    planned = {"baselines": 1000.0, "ges": 500.0}
    assert progress.run_eta(planned, {}, ["baselines", "ges"], {"baselines": 840.0}).startswith(
        "whole run: eta 660s (0.18 h) for 2 stage(s) left (840s spent on them already)")
    assert progress.run_eta(planned, {}, ["baselines"], {"baselines": 5000.0}).startswith("whole run: eta 0s")


def test_run_all_train_seconds_counts_every_attempt(tmp_path):
    """A training resumed after a kill counts both attempts (ppo.train's wall_s restarts at a resume) and not the
    updates the kill lost past its checkpoint; the cost stage's warm-start e2e MLP and BO trials use it, so a
    policy finished just before a kill costs its whole training, not the ~0 s of the attempt that found it done
    (docs/archive/paper_obs/overnight/RUN.md). A BO trial's cost is its seconds.json (training + J), tpe's own
    time when the file is missing or damaged."""
    cfg = ppo.PPOConfig(num_envs=8, num_steps=16, design_dim=1)
    ck, log = str(tmp_path / "p.pt"), str(tmp_path / "log.csv")
    calls = []
    for steps in (8 * 16 * 20, 8 * 16 * 40):
        t0 = time.time()
        ppo.train("mlp", PointMass(8), None, steps, ck, cfg, seed=0, log_csv=log, progress=None)
        calls.append(time.time() - t0)
        if len(calls) == 1:   # a kill after 3 more updates, then the resume's trim
            with open(log, "a") as fh:
                fh.writelines(f"{2560 + 128 * i},{99.0 + i}" + ",0" * 9 + "\n" for i in (1, 2, 3))
            logs.trim_log(log, 2560)
    wall = logs.read_log(log)["wall_s"]
    assert len(wall) == 40 and wall[20] < wall[19]
    assert logs.train_seconds(log) == pytest.approx(wall[19] + wall[39])
    assert wall[39] < logs.train_seconds(log) <= sum(calls)
    run = run_all.Run(str(tmp_path / "run"), run_all.SMOKE, 0, 1)
    bo = policies.PerDesignBO(run, "obstacle", policies.space_of(run_all.SMOKE, "obstacle", "d2"))
    trial = run_all.tpe.Trial(0, np.array([0.8, 0.01]), 1.0, None, 5.0)
    assert bo.trial_seconds(trial) == 5.0
    run_all.write_json(os.path.join(bo.folder(trial.x), "seconds.json"), {"train_s": 100.0, "score_s": 7.0})
    assert bo.trial_seconds(trial) == 107.0
    with open(os.path.join(bo.folder(trial.x), "seconds.json"), "w") as fh:
        fh.write("{")
    assert bo.trial_seconds(trial) == 5.0


def test_runkit_eta_against_schedules_with_known_answers(capsys):
    """One formula for every ETA: on a schedule whose units take the same time, each user's ETA is exact.
    Units of 10 s one at a time: 3 done in 30 s, 7 left -> 70 s. A PPO update of 64 steps in 1 s with 3,840
    steps left -> 1.0 min. The whole run: a stage that ran 10x its plan of 10,000 s makes the next stage's
    plan of 5,000 s take ~10x (the 60 s prior pulls the pace toward 1 by < 1 %); one that ran 2 s of its plan found
    its work done (a rerun's copied baselines) and leaves the pace at 1."""
    assert progress.eta_s(30.0, 3, 7) == pytest.approx(70.0) and progress.eta_s(0.0, 0, 7) is None
    lines = []
    log = ppo.TrainLog(None, lines.append, "mlp", 64 * 61)
    log.write(64, 64, time.time() - 1.0, 0.5, -1.098, float("nan"), 0.0, {"kl": 0.01, "value_loss": 1.0,
                                                                         "entropy": 1.0}, 1e-4, 0.5)
    assert re.search(r"eta\s+1\.0 min", lines[0]), lines[0]
    assert "return        -  level" in lines[0] and "nan" not in lines[0]   # no episode has ended yet
    text = progress.run_eta({"a": 10_000.0, "b": 5_000.0}, {"a": 100_000.0}, ["b"])
    eta = float(re.match(r"whole run: eta (\d+)s", text).group(1))
    assert 49_500 < eta < 50_000 and "x 9.9" in text, text
    reused = progress.run_eta({"a": 10_000.0, "b": 5_000.0}, {"a": 2.0}, ["b"])   # a stage that found its work done
    assert reused.startswith("whole run: eta 5000s") and reused.endswith("--plan's time"), reused


def test_runkit_progress_round_eta_paces_later_rounds_by_their_own_size():
    """Quick's first training round trains 200k steps per specialist, the later ones 10k: after round 1 (2,000 s)
    one round left is ~100 s, not 2,000; after round 2 (150 s) the same-sized round sets the pace; rounds all
    alike pace on every training round; round 0 (the initialisation) never counts."""
    eta = progress.round_eta
    assert eta({"0": 5.0, "1": 2000.0}, 1, 200_000, 10_000) == "eta <= ~100s"
    assert eta({"0": 5.0, "1": 2000.0, "2": 150.0}, 2, 200_000, 10_000) == "eta <= 300s"
    assert eta({"0": 5.0, "1": 100.0, "2": 120.0}, 2, None, 10_000) == "eta <= 220s"
    assert eta({"0": 5.0}, 3, None, 10_000) == "eta -" and eta({"0": 5.0, "1": 9.0}, 0, None, 1) == "eta 0s"


def test_runkit_progress_counts_parallel_and_loaded_units(capsys):
    """With 2 units at a time, the first finished after 100 s means ~2 per 100 s: 9 left -> ~450 s, not 900.
    A resumed stage's units loaded at once (within LOADED_S) do not set the pace: 100 s for unit 3 -> 700 s."""
    for parallel, want in ((1, 900), (2, 450)):
        p = progress.Progress("jobs", 10, every=0, parallel=parallel)
        p.t0 = time.time() - 100
        p(1)
        eta = float(re.search(r"eta\s+(\d+)s", capsys.readouterr().out).group(1))
        assert abs(eta - want) < 5, (parallel, eta)
    p = progress.Progress("jobs", 10, every=0)
    p(1), p(2)
    p.t0 -= 100
    p(3)
    etas = re.findall(r"eta\s+(\S+)", capsys.readouterr().out)
    assert etas[:2] == ["-", "-"] and abs(float(etas[2].rstrip("s")) - 700) < 5, etas


@pytest.mark.slow
def test_runkit_plan_rates_time_each_kind_on_each_task(tmp_path):
    """--rates (the measurement behind TRAIN_RATE / SCORE_RATE) on the smoke batch, inline: its jobs mix the
    policy kinds and tasks as the stages do, each job (policies.rate_job) trains and scores, and the text sets the
    measured rates beside the constants --plan uses."""
    job = functools.partial(policies.rate_job, preset=run_all.SMOKE, steps=128, n_designs=1)
    r = plan.measure_rates(job, ges.SerialExecutor(), 1, str(tmp_path), jobs=2)
    assert r["jobs"] == ["mlp obstacle", "moe ramp"]
    rates = np.array([r["train_steps_per_s"], r["seconds_per_J"], r["played_steps_per_s"]])
    assert rates.shape == (3, 2) and np.all(np.isfinite(rates)) and np.all(rates > 0), rates
    text = plan.rates_text(r)
    assert f"TRAIN_RATE {r['train_rate']:.0f}" in text and f"{plan.TRAIN_RATE:.0f}" in text, text
    assert all(os.path.exists(tmp_path / f"job{i}" / "log.csv") for i in (0, 1))   # out= keeps the jobs' files


@pytest.mark.slow
def test_runkit_plan_counts_the_work_a_run_does(smoke_run, capsys):
    """--plan's arithmetic (presets planned on measured rates) against what the smoke run did: the
    standalone policies' PPO steps, and the control steps of every stored score (score sets and TPE trials),
    with the GES probes at most the plan's round cap."""
    pl, p = plan.plan(run_all.SMOKE, run_all.LAYOUT), run_all.SMOKE
    ep = p.env_config(ballu.BalluConfig()).episode_steps
    names = [name for name, *_ in run_all.baseline_jobs(run_all.Run(smoke_run, p, 3, 1))]
    steps = sum(ppo.load_checkpoint(os.path.join(smoke_run, "policies", n, "policy.pt"))["steps"] for n in names)
    assert steps == pl["baselines"]["ppo_steps"]
    sets = [read_json(f) for f in glob.glob(os.path.join(smoke_run, "scores", "*.json"))]
    searches = [f for f in glob.glob(os.path.join(smoke_run, "tpe", "*.json")) if "per-design-bo" not in f]
    played = sum(len(row) for sc in sets for row in sc["final_x"]) * ep
    played += sum(len(read_json(f)["trials"]) for f in searches) * p.score_episodes * ep
    played += len(searches) * p.peak_episodes * ep                    # each search's peak, scored once more
    assert played == sum(v["score_steps"] for k, v in pl.items() if k != "cost")
    def probed(auto):   # per round, every specialist scores every probe
        return ep * len(p.probe_level_steps) * sum(
            len(h["probes_unit"]) * len(h["mu"]) for f in glob.glob(os.path.join(smoke_run, "ges", "*", "state.json"))
            if ("Kauto" in f) == auto for h in read_json(f)["history"])
    fixed = plan.plan(replace(p, ksens_auto=False), run_all.LAYOUT)
    assert probed(False) == sum(v["probe_steps"] for v in fixed.values())   # fixed K: all at the cap
    assert 0 < probed(True) <= pl["ksens"]["probe_steps"] - fixed["ksens"]["probe_steps"]   # adaptive: a bound
    assert run_all.main(["--preset", "smoke", "--plan", "--out", smoke_run]) == 0   # smoke: planned at the constants
    assert f"{plan.TRAINED_SHARE * plan.TRAIN_RATE:.0f} PPO" in capsys.readouterr().out


def test_run_all_plan_calibrates_once_where_the_run_goes(tmp_path, capsys, monkeypatch):
    """--plan measures the machine once (runkit.plan.calibrate, faked here: the real one takes ~40 s) into the
    output folder and plans at its rates; a second --plan and the run itself reuse it; other workers measure
    anew; a folder holding only the calibration is still free for the run, which keeps it."""
    calls = []

    def fake(job, executor, workers, batch):
        executor.shutdown()
        calls.append(workers)
        return {"workers": workers, "jobs": ["mlp obstacle"] * workers, "train_rate": 444.0, "score_rate": 333.0,
                "seconds": 1.0, "time": "now", "cpu": "test CPU", "batch": list(batch)}

    monkeypatch.setattr(cli, "calibrate", fake)
    monkeypatch.setattr(cli.os, "getloadavg", lambda: (0.1, 0.1, 0.1))   # an idle machine: no warning
    out = str(tmp_path / "q")
    assert run_all.main(["--preset", "quick", "--plan", "--out", out, "--workers", "1"]) == 0
    text = capsys.readouterr().out
    assert f"at {plan.TRAINED_SHARE * 444:.0f} PPO / 333 score" in text and "calibrated on test CPU" in text, text
    assert "warning: load" not in text
    assert os.listdir(out) == [plan.CALIBRATION_FILE] and calls == [1]
    hours = float(re.search(r"total +([\d.]+) h", text).group(1))
    slow = plan.plan(run_all.QUICK, run_all.LAYOUT, 1, plan.TRAINED_SHARE * 444.0, 333.0)
    assert hours == pytest.approx(sum(v["hours"] for v in slow.values()), abs=0.006)
    assert run_all.main(["--preset", "quick", "--plan", "--out", out, "--workers", "1"]) == 0 and calls == [1]
    monkeypatch.setattr(cli.os, "getloadavg", lambda: (1.7, 1.0, 1.0))   # busy: the plan says it will run long
    assert run_all.main(["--preset", "quick", "--plan", "--out", out, "--workers", "2"]) == 0 and calls == [1, 2]
    assert "warning: load average 1.7" in capsys.readouterr().out
    manifest = {"results_format": 0, "preset": "quick", "budgets": {}, "seed": 0, "code_hash": "x"}
    assert check_output(out, manifest, fresh=False) is False   # only a calibration: not a run yet
    open_output(out, manifest, reuse=False)
    assert sorted(os.listdir(out)) == sorted([plan.CALIBRATION_FILE, "manifest.json"])
    run = run_all.Run(out, run_all.QUICK, 0, 2)
    assert cli.calibration(run, policies.rate_job)["train_rate"] == 444.0 and calls == [1, 2]   # --plan's rates
    assert cli.calibration(replace(run, preset=run_all.SMOKE), policies.rate_job) is None   # too small to time
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("x")
    assert run_all.main(["--preset", "quick", "--plan", "--out", str(tmp_path / "other")]) == 2   # not ours
    assert calls == [1, 2]


@pytest.mark.slow
def test_run_all_specialist_round_zero_trains_its_own_budget(tmp_path):
    """Preset.ges_first_round_steps [facts: the authors' first GES round is 3.2x the later ones]: round 0 trains
    to the first round's steps, round 1 adds one round's steps to that; --plan counts the same. A repeated round
    keeps a specialist that finished and retrains one cut short whose checkpoint holds no lanes' state
    (a finished round 0's copied as round 1's: it cannot go on exactly)."""
    p = replace(run_all.SMOKE, ges_first_round_steps=192, ges_round_steps=64)
    space = policies.space_of(p, "obstacle", "d2")
    box = ges.Box.of(space)
    train = policies.TrainSpecialist("obstacle", space, p.ges_round_steps, p, "", p.ges_first_round_steps)
    sampler = ges.GaussianSampler(np.full(2, 0.5), np.full(2, 0.1), box, seed=1)
    a, b = str(tmp_path / "r0.pt"), str(tmp_path / "r1.pt")
    train(0, 0, sampler, None, a)
    stamp = os.stat(a).st_mtime_ns
    train(0, 0, sampler, None, a)   # the round again (a stopped run's rerun): a finished specialist is kept
    assert os.stat(a).st_mtime_ns == stamp
    shutil.copy(a, b)               # round 1's output cut short at 192 of its 256 steps: retrained from round 0's
    train(0, 1, sampler, a, b)
    assert [ppo.load_checkpoint(f)["steps"] for f in (a, b)] == [192, 256] == [p.ges_steps(1), p.ges_steps(2)]
    assert plan.plan(p, run_all.LAYOUT)["ges"]["ppo_steps"] == 4608   # 2 tasks x (3 + 6) specialists x 256


@pytest.mark.slow
def test_run_all_specialist_killed_mid_round_resumes_exactly(tmp_path, monkeypatch):
    """A specialist warm-started from a policy (as ges_warm_start does) and killed mid-round (here in update 5
    of 6; checkpoints every update) goes on from its last checkpoint at the rerun: its checkpoint, best policy
    and learning curve equal an uninterrupted one's, and ges_core_seconds counts its training once (the log's
    rows past the checkpoint are dropped)."""
    p = replace(run_all.SMOKE, ges_first_round_steps=384, ges_round_steps=64)
    monkeypatch.setattr(policies, "ppo_config", lambda preset: replace(
        ppo.PPOConfig(num_envs=preset.ppo_envs, num_steps=preset.ppo_rollout), ckpt_every=1))
    space = policies.space_of(p, "obstacle", "d2")
    warm = str(tmp_path / "warm.pt")
    wide = ges.GaussianSampler(np.full(2, 0.5), np.full(2, 0.3), ges.Box.of(space), seed=5)
    policies.TrainSpecialist("obstacle", space, 128, p)(0, 0, wide, None, warm)   # a 128-step policy
    train = policies.TrainSpecialist("obstacle", space, p.ges_round_steps, p, warm, p.ges_first_round_steps)
    sampler = ges.GaussianSampler(np.full(2, 0.5), np.full(2, 0.1), ges.Box.of(space), seed=1)
    a, b = (str(tmp_path / d / "ckpt" / "spec0_round00.ckpt") for d in "ab")
    os.makedirs(os.path.dirname(a))
    os.makedirs(os.path.dirname(b))
    train(0, 0, sampler, None, a)
    rollout, calls = ppo.rollout, []

    def killed(*args, **kw):
        calls.append(1)
        if len(calls) == 5:
            raise KeyboardInterrupt("simulated kill")
        return rollout(*args, **kw)
    monkeypatch.setattr(ppo, "rollout", killed)
    with pytest.raises(KeyboardInterrupt):
        train(0, 0, sampler, None, b)
    assert ppo.load_checkpoint(b)["steps"] == 128 + 256 and "run" in ppo.load_checkpoint(b)
    train(0, 0, sampler, None, b)
    assert len(calls) == 5 + 2   # the rerun played updates 5 and 6 only
    for x, y in ((a, b), (ppo.best_path(a), ppo.best_path(b))):
        sx, sy = ppo.load_checkpoint(x), ppo.load_checkpoint(y)
        assert sx["steps"] == sy["steps"] and sx["extra"] == sy["extra"]
        assert all(torch.equal(sx["policy"][k], sy["policy"][k]) for k in sx["policy"])
    la, lb = (logs.read_log(f + ".csv") for f in (a, b))
    assert la["steps"].tolist() == lb["steps"].tolist() == [128 + 64 * i for i in range(1, 7)]
    assert la["mean_level"].tolist() == lb["mean_level"].tolist()
    wall = lb["wall_s"].astype(float)
    assert wall[4] < wall[3]   # the rerun's stretch starts again
    state = {"task_seconds": [{"train": [0.0], "probe": [1.5]}]}
    run_all.write_json(str(tmp_path / "b" / "state.json"), state)
    assert run_all.ges_core_seconds(str(tmp_path / "b")) == pytest.approx(1.5 + wall[3] + wall[5])


def test_runkit_plan_packs_specialists_as_the_stages_run_them():
    """A stage's GES runs go side by side, their specialists `workers` at a time: on 2 cores the ges stage's 18
    specialists (3 + 6 per task) pack perfectly, Fig. 7's lone K = 1 run trains one specialist on an otherwise idle
    machine (ALONE_SPEEDUP x the per-core rate), Table III's lone K = 3 run in two waves; on 1 core, one by one."""
    p = replace(run_all.QUICK, ksens_K=(1, 3), table3_inits=("grid", "fps+lloyd"), ges_probes=0, n_test=0)
    spec, rate = p.ges_steps(p.ges_max_rounds), plan.TRAIN_RATE

    def seconds(stage, workers):   # without the process pool's start
        pools = plan.POOLS[stage] * plan.POOL_START_S * (workers > 1)
        return plan.plan(p, run_all.LAYOUT, workers)[stage]["hours"] * 3600 - pools
    assert seconds("ges", 2) == pytest.approx(18 * spec / rate / 2)
    assert seconds("ksens", 2) == pytest.approx(spec / rate / plan.ALONE_SPEEDUP)
    assert seconds("table3", 2) == pytest.approx((spec + spec / plan.ALONE_SPEEDUP) / rate)
    assert [seconds(s, 1) for s in ("ges", "ksens", "table3")] == pytest.approx([18 * spec / rate, spec / rate,
                                                                                 3 * spec / rate])


def test_runkit_plan_runs_per_design_bo_as_the_cost_stage_does():
    """Per-design BO runs its random startup trials `workers` at a time and its TPE trials one at a time, each
    TPE trial waiting for the last one's result: on 2 cores, 3 random trials take two trial-times, 1 random +
    2 TPE trials three, 4 random (of 10) two."""
    def hours(**kw):
        return plan.plan(replace(run_all.QUICK, **kw), run_all.LAYOUT, 2)["cost"]["hours"] - plan.POOL_START_S / 3600
    one = hours(cost_trials=1, tpe_startup=1)
    assert hours(cost_trials=3, tpe_startup=3) == pytest.approx(2 * one)
    assert hours(cost_trials=3, tpe_startup=1) == pytest.approx(3 * one)
    assert hours(cost_trials=4, tpe_startup=10) == pytest.approx(2 * one)


def test_runkit_plan_of_a_small_preset_by_hand():
    """plan's steps and hours for a preset of small numbers, counted by hand: 2 tasks x 2 spaces, 10-step
    episodes; specialists train 30 + 10 steps at the cap of 2 rounds; 1 core at 100 PPO steps/s and 66 score
    steps/s, scores playing 66 % of their steps (2 episodes each): every stage's seconds are its steps / 100."""
    p = replace(run_all.SMOKE, ppo_steps=100, ges_first_round_steps=30, ges_round_steps=10, ges_max_rounds=2,
                score_episodes=2, peak_episodes=3, probe_level_steps=(2,), ges_probes=5, n_test=4, tpe_trials=6,
                tpe_startup=2, cost_trials=3, table3_inits=("grid", "fps+lloyd"), ksens_K=(1, 3), ksens_auto=False,
                ksens_auto_K=None, episode_steps=10)   # the preset's episodes, not the layout's, are played
    layout = plan.Layout(tasks=2, spaces=2, e2e=2, methods=4, searched=3, episode_steps=400)
    rows = plan.plan(p, layout, 1, train_rate=100.0, score_rate=66.0)
    steps = {k: (v["ppo_steps"], v["score_steps"], v["probe_steps"]) for k, v in rows.items()}
    assert steps == {
        "baselines": (1000, 0, 0),      # 2 tasks x (1 baseline design + 2 e2e x 2 spaces) x 100
        "ges": (720, 0, 1800),          # 18 specialists (3 + 6 per task) x 40; x 5 probes x 10 steps x 2 rounds
        "matched": (160, 320, 0),       # 4 cells' e2e MLPs x a specialist's 40 steps; 4 cells x 4 designs x 20
        "table2": (0, 3120, 0),         # (2 + 4 cells x 4 methods x 4 designs + 4 x 3 searches x 6 trials) x 20
                                        # + 4 x 3 peaks x 30
        "table3": (120, 80, 300),       # grid's K = 3 run: 3 x 40; 4 designs x 20; 3 x 5 x 10 x 2
        "ksens": (40, 80, 100),         # K = 1's run: 40; 4 x 20; 1 x 5 x 10 x 2
        "cost": (300, 60, 0),           # 3 BO trials: 3 x 100 PPO steps, 3 x 20 score steps
        "figures": (0, 0, 0)}
    seconds = {k: 3600 * v["hours"] for k, v in rows.items()}
    assert seconds == pytest.approx({"baselines": 10.0, "ges": 25.2, "matched": 4.8, "table2": 31.2, "table3": 5.0,
                                     "ksens": 2.2,
                                     "cost": 3.6, "figures": 40.0})   # figures: FIGURES_S, a fixed cost
    # adaptive K adds a run at its start and bound K = max(K_d2, K_d3) = 6 (ksens_auto_K None): 6 x 40; 4 x 20; probes 6 x 5 x 10 x 2 and its
    # checks, every one of 6 specialists scoring 5 (= F) of each of 6 territories' designs, 10 steps, 2 rounds
    auto = plan.plan(replace(p, ksens_auto=True), layout, 1, train_rate=100.0, score_rate=66.0)["ksens"]
    assert (auto["ppo_steps"], auto["score_steps"], auto["probe_steps"]) == (40 + 240, 160, 100 + 600 + 3600)
    two = plan.plan(p, layout, 2, train_rate=100.0, score_rate=66.0)
    # table3's 3 specialists on 2 cores: a wave of 2, then 1 alone at 2 / 1.68 the per-core rate: 2 + 1.68 core
    # turns for 3 jobs' work, 0.68 of a 40-step specialist idle; its one score set alone, 1.68 - 1 idle
    assert 3600 * two["table3"]["hours"] == pytest.approx(((120 + 0.68 * 40) / 100 + (80 + 0.68 * 80 + 300) / 100)
                                                          / 2 + 2 * 2.0)   # + 2 process pools' start


def test_runkit_logs_training_rate_is_total_steps_over_total_time(tmp_path):
    """The report's PPO rate is every training's steps over its time: with one batch per update, the harmonic mean
    of the logs' update rates (updates at 100, 300, 200 and a specialist's 400 steps/s of 600 steps: 2,400 steps in
    12.5 s). A damaged log or another CSV file is skipped, not fatal."""
    for name, rates in (("a", (100.0, 300.0)), ("b", (200.0,))):
        os.makedirs(tmp_path / "policies" / name)
        with open(tmp_path / "policies" / name / "log.csv", "w") as fh:
            fh.write("steps,wall_s,steps_per_s\n" + "".join(f"{600 * (i + 1)},1.0,{r}\n" for i, r in enumerate(rates)))
    os.makedirs(tmp_path / "ges" / "x" / "ckpt")
    (tmp_path / "ges" / "x" / "ckpt" / "spec0_round00.ckpt.csv").write_text("steps,wall_s,steps_per_s\n600,1,400\n")
    (tmp_path / "ges" / "x" / "log.csv").write_text("steps,wall_s,steps_per_s\n600,1.0\n")   # a short row
    (tmp_path / "test_scores.csv").write_text("task,J\nobstacle,12.5\n")                      # not a training log
    rate, n = logs.training_rate(str(tmp_path))
    assert rate == pytest.approx(2400 / (600 / 100 + 600 / 300 + 600 / 200 + 600 / 400)) and n == 3


def test_report_cost_claim_needs_a_saving_beyond_the_drift():
    """One timing per side has no CI: a saving within the machine's +-20 % drift (0.4 %) is 'not resolved', not
    'supported'; 37 % is 'supported', a 30 % loss 'not supported'."""
    for red, want in ((0.4, "not resolved"), (37.0, "supported"), (-30.0, "not supported")):
        rows = [l for l in tables.report_claims({"cost": {"reduction_pct": red}}) if "per-design BO" in l]
        assert len(rows) == 1 and f"| {want} |" in rows[0], (red, rows)


def test_report_cost_claim_from_the_break_even_trial_count():
    """GES pays a fixed cost, then a cheap J per trial; BO a training per trial: n* = fixed / (BO - GES per trial)
    with a bootstrap interval over BO's trials; supported when even the interval's top (+20 % drift) is < 40."""
    cost = {"bo_trial_s": [100.0, 100.0, 100.0], "ges_fixed_s": 300.0, "ges_per_trial_s": 10.0}
    n, lo, hi = tables.break_even(cost)
    assert n == pytest.approx(300 / 90) and lo == pytest.approx(n) and hi == pytest.approx(n)
    assert tables.cost_claim(cost)[1] == "supported"
    assert tables.cost_claim(dict(cost, ges_fixed_s=4000.0))[1] == "not resolved"     # n* = 44.4, within drift
    assert tables.cost_claim(dict(cost, ges_fixed_s=9000.0))[1] == "not supported"    # n* = 100
    assert tables.break_even(dict(cost, ges_per_trial_s=150.0))[0] == math.inf        # BO's trial is cheaper
    spread = dict(cost, bo_trial_s=[50.0, 100.0, 150.0])
    n, lo, hi = tables.break_even(spread)
    assert lo < n < hi and hi == pytest.approx(300 / (50 - 10), rel=0.05)   # the interval's top: all trials at 50


def test_report_figures_gait_features_of_a_known_hop():
    """Gait features of a known toe trajectory: a 2.5 Hz hop of 10 cm at 0.05 s per control step, 8 steps a
    period, toe heights 0.4 cm + 10 cm x max(0, sin(pi i / 4)): up 7.5, 10.4 and 7.5 cm at steps 1-3 of each 8,
    on the floor (0.4 cm, under the 2 cm bar) the other 5, so both toes are up 3 / 8 = 37.5 % of the time."""
    z = np.clip(0.1 * np.sin(np.pi * np.arange(400) / 4), 0, None) + 0.004
    f = figures.gait_features(np.stack([z, z + 0.001], axis=1), 0.05)
    assert f["step_hz"] == pytest.approx(2.5) and f["peak_toe_cm"] == pytest.approx(10.4)
    assert f["airborne_pct"] == pytest.approx(37.5)


def test_report_designs_needed_at_80_percent_power():
    """The designs a paired test needs to resolve a difference at 80 % power: (2.8 sd / mean)^2."""
    rng = np.random.default_rng(0)
    base = rng.normal(20, 5, 20)
    d = rng.normal(0.5, 2.0, 20)
    res = {"a": {"scores": (base + d).tolist()}, "b": {"scores": base.tolist()}}
    want = math.ceil((2.8 * d.std(ddof=1) / abs(d.mean())) ** 2)
    assert tables.designs_needed(res, "a") == f"a verdict needs ~{want} test designs at the measured spread"
    res["a"]["scores"] = (base + 3.0).tolist()
    assert tables.designs_needed(res, "a") == "every comparison resolved"


@pytest.mark.slow
def test_run_all_damaged_files_are_redone_or_named(smoke_run, tmp_path, capsys):
    """A rerun on a damaged results folder: what can be redone exactly (a stage's result, a score set, a TPE study,
    a standalone policy, timing records) is moved aside and redone with a warning, giving the same raw numbers;
    a damaged manifest or GES run is a one-line error naming the file and what to do. Never torch's advice."""
    import shutil
    out = str(tmp_path / "run")
    shutil.copytree(smoke_run, out)
    args = ["--preset", "smoke", "--out", out, "--workers", "1", "--seed", "3"]

    def damage(rel, how):
        path = os.path.join(out, rel)
        data = read_bytes(path)
        write_bytes(path, DAMAGES[how](data))
        return path, data

    ges_dir = os.path.join("ges", "obstacle-d2-K3-fps-lloyd")
    for rel, how, words in (("manifest.json", "truncated", ["manifest.json is damaged", "--fresh"]),
                            (os.path.join(ges_dir, "state.json"), "random bytes",
                             ["state.json is damaged (not a readable GES state", "delete the folder", ges_dir]),
                            (os.path.join(ges_dir, "ckpt", "spec1_round01.ckpt"), "truncated",
                             ["spec1_round01.ckpt is damaged (not a readable ppo.py checkpoint", "--fresh"]),
                            (os.path.join(ges_dir, "ckpt", "spec0_round01.ckpt"), "a pickle",
                             ["spec0_round01.ckpt is damaged (not a readable ppo.py checkpoint", "--fresh"])):
        path, data = damage(rel, how)
        assert run_all.main(args) == 2, rel
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and all(w in err for w in words) and "weights_only" not in err, err
        write_bytes(path, data)
    redo = {os.path.join("stages", "table2.json"): "a JSON list",
            os.path.join("scores", "test-obstacle-d2-mlp.json"): "truncated",
            os.path.join("tpe", "obstacle-d2-ges.json"): "another format",
            os.path.join("policies", "mlp-obstacle-d2", "policy.pt"): "truncated",
            "stage_seconds.json": "random bytes"}
    damaged = {rel: DAMAGES[how](damage(rel, how)[1]) for rel, how in redo.items()}
    assert run_all.main(args) == 0
    said = capsys.readouterr().out
    for rel in redo:
        assert f"{os.path.join(out, rel)} is damaged" in said
        assert read_bytes(os.path.join(out, rel) + ".damaged") == damaged[rel]   # moved aside, as it was
    assert "stage table2: start" in said and "weights_only" not in said
    mine, ref = raw_numbers(out), raw_numbers(smoke_run)   # the redone parts are the same numbers
    assert mine.keys() == ref.keys() and [k for k in ref if mine[k] != ref[k]] == []
    a, b = (read_json(os.path.join(d, "results.json"))["stages"] for d in (smoke_run, out))
    assert _numbers_only(a) == _numbers_only(b)


@pytest.mark.slow
def test_run_all_what_a_user_sees(smoke_run, capsys):
    """Progress lines: J to two decimals. The report:
    every table set apart by blank lines (Markdown would merge them), the head-to-head table once, Table III's
    min / max at the means' precision, and D3's leg length l defined."""
    assert (run_all.fmt_y(1.0999999999999999), run_all.fmt_y(None)) == ("1.10", "failed")
    rep = read_text(os.path.join(smoke_run, "REPORT.md")).splitlines() + [""]   # the file ends after a table
    for i, line in enumerate(rep):
        if line.startswith("|") and not rep[i - 1].startswith("|"):
            assert rep[i - 1] == "", (i, line)
        if line.startswith("|") and not rep[i + 1].startswith("|"):
            assert rep[i + 1] == "", (i, line)
    assert sum("Head-to-head" in line for line in rep) == 1
    assert sum(line.startswith("| task | space | vs baseline policy") for line in rep) == 1
    t3 = [line for line in rep if line.startswith("| fps+lloyd |")][0].split(" | ")
    assert re.fullmatch(r"\d+\.\d \(24\)", t3[2]) and re.fullmatch(r"\d+\.\d \(52\)", t3[3]), t3
    assert any("l = l_f = l_t" in line for line in rep)

# ----------------------------------------------------------------------------------------------------------
# Use what a run trained: `python run_all.py watch|score` (experiments/use.py, report/animate.py). Each test
# plays at most a few short episodes of a committed run (docs/quick, docs/overnight/seed0).
# ----------------------------------------------------------------------------------------------------------
USE_HERE = os.path.dirname(os.path.abspath(__file__))
QUICK_RUN, SEED0_RUN = os.path.join(USE_HERE, "docs", "quick"), os.path.join(USE_HERE, "docs", "overnight", "seed0")
MLP_OBST = os.path.join(QUICK_RUN, "policies", "mlp-obstacle-d2", "policy.pt")   # quick keeps no _best


def use_main(capsys, *argv) -> tuple:
    """(exit code, stdout, stderr) of `python run_all.py argv...` (watch and score: experiments/use.py's main, which
    run_all.main runs in a child process: test_run_all_watch_score_run_use)."""
    code = use.main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


# --- designs and levels -------------------------------------------------------------------------------------
def test_use_design_arg_forms():
    d2, d3 = ballu.d2("obstacle"), ballu.d3("ramp")
    opt = use.design_arg("optimum", d2)
    assert opt.full.tolist() == [0.45, 0.45, 0.88, 0.008] and opt.theta.tolist() == [0.88, 0.008]
    assert use.design_arg("optimum", d3).theta.tolist() == [0.88, 0.008, 0.45]   # l: the baseline's legs
    assert use.design_arg("baseline", d2).full.tolist() == ballu.BASELINE.tolist()   # outside the box, allowed
    d = use.design_arg(" gcr=0.8, spcf=0.01 ", d2)
    assert d.full.tolist() == [0.45, 0.45, 0.8, 0.01]
    assert use.design_arg("gcr=0.8,spcf=0.01,l=0.3", d3).full.tolist() == [0.3, 0.3, 0.8, 0.01]
    assert use.design_arg("l_f=0.45,l_t=0.45,gcr=0.8,spcf=0.01", d2).full.tolist() == d.full.tolist()
    with pytest.raises(use.UseError, match="l_f = l_t = l: give l"):   # D3 ties the legs to l
        use.design_arg("gcr=0.8,spcf=0.01,l_f=0.3", d3)


@pytest.mark.parametrize("text, words", [
    ("gcr=0.95,spcf=0.01", ["gcr=0.95", "allowed range [0.72, 0.9]"]),
    ("spcf=0.01", ["gcr=0.7", "not given", "[0.72, 0.9]"]),
    ("gcr=0.8,spcf=2", ["spcf=2", "[0.001, 0.1]"]),
    ("mass=3", ["'mass=3'", "gcr", "optimum"]),
    ("gcr=high", ["'gcr=high'"]),
    ("gcr=0.8,l_f=0.3", ["l_f is not free", "0.45"]),
    ("", ["is not name=value"]),
])
def test_use_design_arg_errors(text, words):
    with pytest.raises(use.UseError) as e:
        use.design_arg(text, ballu.d2("obstacle"))
    msg = str(e.value)
    assert "\n" not in msg and all(w in msg for w in words), msg


def test_use_designs_file(tmp_path):
    space = ballu.d2("obstacle")
    f = tmp_path / "d.csv"
    f.write_text("label,gcr,spcf\nlow,0.75,0.005\n,0.85,0.02\n")
    ds = use.designs_file(str(f), space)
    assert [d.label for d in ds] == ["low", "gcr=0.85,spcf=0.02"] and ds[0].full.tolist() == [0.45, 0.45, 0.75, 0.005]
    f.write_text("gcr,spcf\n0.8,0.01\n0.99,0.01\n")
    with pytest.raises(use.UseError, match=r"line 3: .*gcr=0.99.*allowed range"):
        use.designs_file(str(f), space)
    with pytest.raises(use.UseError, match="no such file"):
        use.designs_file(str(tmp_path / "none.csv"), space)


def test_use_level_arg():
    q = use.run_of(QUICK_RUN).preset
    assert use.level_arg(None, None, "obstacle", q) == 28 and use.level_arg(None, None, "ramp", q) == 40
    assert use.level_arg(None, 30.1, "obstacle", q) == 30 and use.level_arg(None, 30, "obstacle", q) == 30
    deg = float(ballu.level_score("ramp", 33))
    assert use.level_arg(None, deg + 0.1, "ramp", q) == 33
    for level, height in ((75, None), (-1, None), (None, 80.0)):
        with pytest.raises(use.UseError, match="allowed range"):
            use.level_arg(level, height, "obstacle", q)


# --- policies -----------------------------------------------------------------------------------------------
def test_use_resolve_policies():
    t = use.resolve([QUICK_RUN, "mlp", "obstacle-d2"])
    assert t.preset.name == "quick" and t.policy is not None and t.space.names == ("gcr", "spcf")
    assert use.resolve([MLP_OBST, "obstacle-d2"]).preset.name == "quick"   # the run folder it lies in
    g = use.resolve([SEED0_RUN, "ges", "obstacle-d2"])
    assert g.preset.name == "overnight" and len(g.ges.ckpt) == 3
    assert g.ges.run_dir.endswith(os.path.join("ges", "obstacle-d2-K3-fps-lloyd"))   # Table II's main GES run
    assert all(os.path.exists(ppo.scored_path(c)) for c in g.ges.ckpt)
    assert use.resolve([SEED0_RUN, "mlp_matched", "ramp-d3"]).policy is not None


@pytest.mark.parametrize("argv, words", [
    ([QUICK_RUN, "mlp", "obstacle-d4"], ["cell 'obstacle-d4'", "obstacle-d2"]),
    ([QUICK_RUN, "ppo", "obstacle-d2"], ["method 'ppo'", "mlp_matched"]),
    ([QUICK_RUN, "mlp_matched", "obstacle-d2"], ["no mlp_matched policy"]),
    (["/nonexistent", "mlp", "obstacle-d2"], ["not a run_all output folder"]),
    ([os.path.join(QUICK_RUN, "policies", "mlp-ramp-d2", "policy.pt"), "obstacle-d2"], ["the ramp task", "not obstacle"]),
    (["/nonexistent.pt", "obstacle-d2"], ["does not exist"]),
    ([QUICK_RUN, "mlp", "ramp-d2", "--rule", "strict"], ["--rule strict", "ramp"]),
])
def test_use_bad_input_is_one_line(capsys, argv, words):
    code, out, err = use_main(capsys, "score", *argv, "--episodes", "1")
    assert code == 2 and err.count("\n") == 1 and all(w in err for w in words), err


def test_use_ges_routes_as_ges_route():
    t = use.resolve([SEED0_RUN, "ges", "obstacle-d2"])
    rng = np.random.default_rng(0)
    theta = t.space.sample_uniform(rng, 12)
    mine = [use.route(t.ges, th)[0] for th in theta]
    assert mine == t.ges.route(theta).tolist()
    assert mine == ges.route_unit(t.ges.space.to_unit(theta), t.ges.mu_unit, t.ges.sigma_unit).tolist()
    assert len(set(mine)) > 1   # the sample reaches several territories


# --- score --------------------------------------------------------------------------------------------------
def test_use_score_equals_ballu_score():
    t = use.resolve([QUICK_RUN, "mlp", "obstacle-d2"], workers=1)
    d = use.design_arg("gcr=0.8,spcf=0.01", t.space)
    row = use.score(t, [d], episodes=3, workers=1)[0]
    j, x = ballu.score(ppo.load_policy(MLP_OBST), d.full, "obstacle", episodes=3, start_level=28, final_x=True)
    assert row["J"] == float(j[0]) and row["x"] == [float(v) for v in x[0]]
    assert row["walk_ok"] and row["levels"][0] == 28 and len(row["levels"]) == 3


def test_use_ges_score_picks_the_routed_specialist():
    t = use.resolve([SEED0_RUN, "ges", "obstacle-d2"], workers=1)
    d = use.design_arg("optimum", t.space)
    row = use.score(t, [d], episodes=2, workers=1)[0]
    k = int(t.ges.route(d.theta)[0])
    assert row["specialist"] == k
    assert row["log_density"] == pytest.approx(ges.log_density(t.ges.space.to_unit(d.theta[None]), t.ges.mu_unit,
                                                               t.ges.sigma_unit)[0, k])
    j = ballu.score(ppo.load_policy(ppo.scored_path(t.ges.ckpt[k])), d.full, "obstacle", episodes=2, start_level=28)
    assert row["J"] == float(j[0])


def test_use_score_command_writes_csv(tmp_path, capsys):
    out = tmp_path / "s.csv"
    code, text, _ = use_main(capsys, "score", QUICK_RUN, "mlp", "obstacle-d2", "--design", "optimum", "--design",
                             "baseline", "--episodes", "2", "--workers", "1", "--out", out)
    assert code == 0 and "J " in text and str(out) in text
    lines = out.read_text().splitlines()
    assert lines[0].startswith("design,l_f,l_t,gcr,spcf,J_cm,rule,cleared,band,short,") and len(lines) == 3
    assert lines[2].startswith("baseline,0.45,0.45,0.7,0.002")
    rows = list(csv_module.DictReader(out.read_text().splitlines()))
    assert all(r["rule"] == "facts" and int(r["cleared"]) + int(r["band"]) + int(r["short"]) == 2 for r in rows)
    assert "outcome" in text and "cleared" in text


def test_use_score_strict_rule_is_ballu_score_strict():
    t = use.resolve([QUICK_RUN, "mlp", "obstacle-d2"], workers=1)
    d = use.design_arg("baseline", t.space)
    row = use.score(t, [d], episodes=3, workers=1, rule="strict")[0]
    j = ballu.score(ppo.load_policy(MLP_OBST), d.full, "obstacle", episodes=3, start_level=28, strict=True)
    assert row["J"] == float(j[0]) and row["walk_ok"]
    assert list(row["outcome"]) == list(ballu.episode_outcome("obstacle", row["x"]))


# --- watch --------------------------------------------------------------------------------------------------
def test_use_watch_renders_a_gif(tmp_path, capsys):
    from PIL import Image
    out = tmp_path / "a.gif"
    code, text, _ = use_main(capsys, "watch", QUICK_RUN, "mlp", "obstacle-d2", "--design", "optimum", "--max-steps", "9",
                             "--every", "4", "--size", "160x120", "--out", out)
    assert code == 0 and out.exists() and str(out) in text
    with Image.open(out) as im:
        assert im.n_frames > 1 and im.size == (160, 120 + animate.HEADER)


def test_use_watch_side_by_side(tmp_path, capsys):
    from PIL import Image
    out = tmp_path / "vs.gif"
    code, text, _ = use_main(capsys, "watch", SEED0_RUN, "ges", "obstacle-d2", "--vs", "mlp", "--max-steps", "5",
                             "--size", "120x90", "--out", out)
    assert code == 0 and "specialist" in text
    with Image.open(out) as im:
        assert im.size == (240, 90 + animate.HEADER) and im.n_frames > 1


def test_use_watch_plays_the_episode_J_plays():
    """The film's episode is J's episode at that level: the same final x."""
    t = use.resolve([QUICK_RUN, "mlp", "obstacle-d2"], workers=1)
    d = use.design_arg("gcr=0.85,spcf=0.03", t.space)
    pol, _ = use.play(t, d)
    f = animate.film(pol, "obstacle", d.full, 28, t.preset.env_config(ballu.policy_config(pol, "obstacle")),
                     every=100, size=(64, 48))
    row = use.score(t, [d], episodes=1, workers=1)[0]
    assert f["final_x"] == row["x"][0] and len(f["frames"]) == 5


def test_use_watch_mp4_needs_ffmpeg(tmp_path, capsys):
    if shutil.which("ffmpeg"):
        pytest.skip("ffmpeg is installed")
    code, _, err = use_main(capsys, "watch", QUICK_RUN, "mlp", "obstacle-d2", "--max-steps", "2", "--out",
                            tmp_path / "a.mp4")
    assert code == 2 and "ffmpeg" in err and err.count("\n") == 1


def test_use_help_lists_examples(capsys):
    for argv in ([], ["watch"], ["score"]):
        with pytest.raises(SystemExit) as e:
            use.main(argv + ["--help"])
        assert e.value.code == 0 and "examples:" in capsys.readouterr().out


# ----------------------------------------------------------------------------------------------------------
# One command-line vocabulary (runkit/args.py, experiments/args.py; issue 97): --design, --out, --workers, help with examples
# ----------------------------------------------------------------------------------------------------------
COMMAND_LINES = [   # (the module holding a file's main, its name, argv); [] = run with no argument
    ("experiments.ballu_bench", "main", []), ("experiments.ballu_bench", "main", ["bench", "--help"]),
    ("experiments.ballu_bench", "main", ["strip", "--help"]),
    ("ppo", "_main", []), ("ppo", "_main", ["bench", "--help"]),
    ("experiments.ges_demo", "main", []), ("experiments.ges_demo", "main", ["demo", "--help"]),   # ges.py's (a child)
    ("experiments.ges_demo", "main", ["sweep", "--help"]), ("experiments.ges_demo", "main", ["bench", "--help"]),
    ("tpe", "main", []), ("tpe", "main", ["demo", "--help"]), ("tpe", "main", ["bench", "--help"]),
    ("experiments.use", "main", ["--help"]), ("experiments.use", "main", ["watch", "--help"]),
    ("experiments.use", "main", ["score", "--help"]),
    ("experiments.ballu_capability", "main", ["--help"]),
    ("experiments.ges_adaptive", "main", ["--help"]), ("experiments.ges_adaptive", "main", ["run", "--help"]),
    ("experiments.ges_adaptive", "main", ["report", "--help"]),
    ("experiments.ges_demo", "main", ["--help"]), ("experiments.ges_lanes", "main", ["--help"]),
    ("experiments.ppo_ballu", "main", ["--help"]), ("experiments.ppo_ballu", "main", ["train", "--help"]),
    ("experiments.ppo_ballu", "main", ["strip", "--help"]),
    ("experiments.ppo_diagnose", "main", ["--help"]), ("experiments.ppo_protocol", "main", ["--help"]),
    ("experiments.probe_agreement", "main", ["--help"]), ("experiments.same_results", "main", ["--help"]),
    ("run_all", "main", ["--help"]), ("experiments.step_matched", "main", ["--help"]),
    ("experiments.ges_territories", "main", ["--help"]), ("experiments.ges_screen", "main", ["--help"]),
    ("experiments.rerun", "main", ["--help"]), ("experiments.authors_setup", "main", ["--help"]),
    ("experiments.stay_band", "main", ["--help"]),
]


@pytest.mark.parametrize("module, fn, argv", COMMAND_LINES, ids=[f"{m}:{' '.join(a) or '(none)'}"
                                                                 for m, _, a in COMMAND_LINES])
def test_every_command_line_help_lists_an_example(module, fn, argv, capsys):
    """--help (and a top-level file run with no argument) exits 0 and ends with examples: one for each command a
    program lists, the command's own for a command's help; a --workers defaults to every core."""
    import importlib
    with pytest.raises(SystemExit) as e:
        getattr(importlib.import_module(module), fn)(argv)
    out = capsys.readouterr().out
    assert e.value.code == 0 and "examples:\n" in out, out
    lines = [s.split() for s in out.split("examples:\n", 1)[1].splitlines() if s.strip().startswith("python ")]
    said = {w[3 if w[1] == "-m" else 2] for w in lines if len(w) > (3 if w[1] == "-m" else 2)}
    assert lines, out
    listed = re.search(r"positional arguments:\n  \{([a-z,]+)\}", out)   # a program's commands
    for cmd in listed[1].split(",") if listed else argv[:1] if argv[:1] != ["--help"] else []:
        assert cmd in said, (cmd, said)
    options = " ".join(out.split("examples:\n")[0].split())
    assert "--workers WORKERS" not in options or "default: every core" in options


LIBRARY = ("ballu.py", "ppo.py", "ges.py", "tpe.py", "codesign", "report", "runkit")   # the tools: run_all, experiments/


def project_imports(path: str, here: str) -> set:
    """The project modules a file imports, lazy imports and importlib.import_module("...") included (read with
    ast, not by importing: an import inside a function counts)."""
    names, tree = set(), __import__("ast").parse(open(path).read())
    for node in __import__("ast").walk(tree):
        kind = type(node).__name__
        if kind == "Import":
            names |= {a.name for a in node.names}
        elif kind == "ImportFrom" and node.module and not node.level:
            names |= {node.module} | {f"{node.module}.{a.name}" for a in node.names}
        elif kind == "Call" and getattr(node.func, "attr", getattr(node.func, "id", "")) in ("import_module",
                                                                                            "__import__"):
            names |= {a.value for a in node.args[:1] if isinstance(getattr(a, "value", None), str)}
    def module(n):   # a.b names the file a/b.py, else the package a's __init__.py; a top-level file a.py
        parts = n.split(".")
        for k in range(len(parts), 0, -1):
            f = os.path.join(here, *parts[:k])
            if os.path.isfile(f + ".py"):
                return ".".join(parts[:k])
            if os.path.isfile(os.path.join(f, "__init__.py")):
                return ".".join(parts[:k])
        return None
    return {m for m in map(module, names) if m}


def project_files(here: str) -> dict:
    """{module name: path} of every project module (top-level files and packages, tests and docs/ left out)."""
    out = {}
    for f in sorted(glob.glob(os.path.join(here, "*.py")) + glob.glob(os.path.join(here, "*", "*.py"))):
        rel = os.path.relpath(f, here)
        if rel.startswith(("test_", "docs")):
            continue
        name = rel[:-3].replace(os.sep, ".")
        out[name[:-len(".__init__")] if name.endswith(".__init__") else name] = f
    return out


def test_library_imports_no_tool():
    """No module of the library (ballu, ppo, ges, tpe, codesign/, report/, runkit/) imports experiments/ or run_all,
    not even lazily: a library file knows nothing of the tools built on it (issue 112)."""
    here = os.path.dirname(os.path.abspath(__file__))
    files = project_files(here)
    lib = {m: f for m, f in files.items() if any(m == x[:-3] or m.split(".")[0] == x for x in LIBRARY)}
    assert {"ballu", "ges", "ppo", "tpe", "codesign.policies", "report.figures", "runkit.args"} <= set(lib)
    bad = {m: sorted(i for i in project_imports(f, here) if i.split(".")[0] in ("experiments", "run_all"))
           for m, f in lib.items()}
    assert not {m: i for m, i in bad.items() if i}


def test_project_has_no_import_circle():
    """No import circle among the project's modules, lazy imports included (a depth-first search for a back edge)."""
    here = os.path.dirname(os.path.abspath(__file__))
    files = project_files(here)
    graph = {m: project_imports(f, here) - {m} for m, f in files.items()}
    state, path = {}, []
    def visit(m):
        state[m] = "open"
        path.append(m)
        for n in sorted(graph.get(m, ())):
            if state.get(n) == "open":
                raise AssertionError("import circle: " + " -> ".join(path[path.index(n):] + [n]))
            if n not in state:
                visit(n)
        path.pop()
        state[m] = "done"
    for m in sorted(graph):
        if m not in state:
            visit(m)


NOT_NUMBERS = {   # modules the hashed files import that make no number: what each does instead
    "runkit": "the package's docstring", "runkit.args": "command lines", "runkit.files": "atomic writes, reads",
    "runkit.logs": "reads the training log", "runkit.plan": "--plan's arithmetic and the rate jobs' timing",
    "runkit.pool": "executors (test_ges_process_pool_equals_serial: any gives the same numbers)",
    "runkit.progress": "progress lines", "runkit.settings": "settings' checks"}


@pytest.mark.parametrize("item, words", [
    ("setup=bogus_xyz", "Preset.setup='bogus_xyz' not allowed: 'table' (paper Table I) or 'authors'"),
    ("policy_rule=bogus", "Preset.policy_rule='bogus' not allowed: 'best' or 'last'"),
    ("ppo_start=up", "Preset.ppo_start='up' not allowed: one of ('task', 'spread', 'zero')"),
    ("table3_inits=grid,nope", "Preset.table3_inits=('grid', 'nope') not allowed: each one of grid,random,fps"),
    ("cost_space=d9", "Preset.cost_space='d9' not allowed: one of ('d2', 'd3')")])
@pytest.mark.parametrize("then", [["--plan"], ["--only", "table1"]])
def test_run_all_set_is_checked_before_anything_runs(item, words, then, tmp_path, capsys):
    """Every --set value is checked before anything runs, --plan included: one line naming the field, the value as
    typed and what is allowed (the preset checks itself: runkit.settings), exit 2, nothing written."""
    out = tmp_path / "x"
    assert run_all.main(["--preset", "smoke", "--set", item, "--out", str(out), "--workers", "1"] + then) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("run_all.py: error: --set ") and words in err, err
    assert not out.exists()


def test_code_hash_covers_every_file_that_makes_numbers():
    """run_all.HASHED_FILES holds every project module its files import, lazy imports included, but those of
    NOT_NUMBERS: a new module that makes numbers must join the hash (or say here why it makes none)."""
    here = os.path.dirname(os.path.abspath(__file__))
    files = project_files(here)
    hashed = {f[:-3].replace("/", ".") for f in run_all.HASHED_FILES}
    seen, todo = set(), sorted(hashed)
    while todo:
        m = todo.pop()
        if m not in seen:
            seen.add(m)
            todo += sorted(project_imports(files[m], here))
    assert seen - hashed - set(NOT_NUMBERS) == set()
    assert "runkit.box" in hashed and set(NOT_NUMBERS) <= seen   # no stale entry


def test_run_all_watch_score_run_use(tmp_path):
    """`python run_all.py score ...` runs experiments/use.py's command line (in a child process, from any folder):
    its one-line error and exit code 2 on an unknown method."""
    here = os.path.dirname(os.path.abspath(__file__))
    p = subprocess.run([sys.executable, os.path.join(here, "run_all.py"), "score", QUICK_RUN, "nope", "obstacle-d2"],
                       cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert p.returncode == 2 and p.stderr.count("\n") == 1 and p.stderr.startswith("run_all.py: error: "), p.stderr


def test_top_level_files_run_bare_print_help():
    """`python ballu.py`, `ppo.py`, `ges.py`, `tpe.py` with no argument: the help, exit 0 (their __main__ blocks)."""
    here = os.path.dirname(os.path.abspath(__file__))
    for name in ("ballu.py", "ppo.py", "ges.py", "tpe.py"):
        p = subprocess.run([sys.executable, name], cwd=here, capture_output=True, text=True, timeout=120)
        assert p.returncode == 0 and f"python {name} " in p.stdout and "examples:" in p.stdout, (name, p.stderr)


def test_args_one_design_form_across_command_lines():
    """`--design gcr=0.86,spcf=0.008` is one design in run_all.py watch (on D2), ballu.py strip and ppo_ballu's
    parsers; `optimum` and `baseline` too; `l` sets both legs as D3's `l` does."""
    from experiments import args, ballu_bench
    text, d2, d3 = "gcr=0.86,spcf=0.008", ballu.d2("obstacle"), ballu.d3("obstacle")
    watch = use.parser().parse_args(["watch", QUICK_RUN, "mlp", "obstacle-d2", "--design", text])
    strip = ballu_bench.parser().parse_args(["strip", "--out", "s.png", "--design", text])
    train = ppo_ballu._parser().parse_args(["train", "--out", "o", "--design", text])
    want = [0.45, 0.45, 0.86, 0.008]
    assert use.design_arg(watch.design, d2).full.tolist() == strip.design.tolist() == want
    assert ppo_ballu.design_sampler(train.design).design.tolist() == want
    for name in ("optimum", "baseline"):
        assert args.full_design(name).tolist() == use.design_arg(name, d2).full.tolist()
    assert args.full_design("l=0.3,gcr=0.8,spcf=0.01").tolist() == use.design_arg("gcr=0.8,spcf=0.01,l=0.3",
                                                                                  d3).full.tolist()
    assert args.full_design("l_f=0.3,gcr=0.8").tolist() == [0.3, 0.45, 0.8, 0.002]   # any design, not only a box's
    with pytest.raises(args.BadArg, match="l sets both legs"):
        args.full_design("l=0.3,l_f=0.4")


def test_args_old_forms_still_work_with_a_deprecation(capsys):
    """Four numbers l_f,l_t,gcr,spcf and the flags that became commands (`--demo DIR`): read, with one line
    naming the new form."""
    from experiments import args
    assert args.full_design("0.45,0.45,0.86,0.008").tolist() == args.full_design("gcr=0.86,spcf=0.008").tolist()
    assert capsys.readouterr().err.strip() == ("--design 0.45,0.45,0.86,0.008: four numbers are deprecated; use "
                                               "--design l_f=0.45,l_t=0.45,gcr=0.86,spcf=0.008")
    old = ges_demo.OLD_FLAGS
    assert args.legacy(["--seed", "1", "--demo", "d", "--K", "2"], old, "python ges.py") == [
        "demo", "--out", "d", "--seed", "1", "--K", "2"]
    assert capsys.readouterr().err == ("python ges.py: --demo is deprecated: use python ges.py demo --out d --seed 1 "
                                       "--K 2\n")
    assert args.legacy(["--demo=d"], old, "p") == ["demo", "--out", "d"]
    assert args.legacy(["--sweep"], old, "p") == ["sweep"] and args.legacy(["demo"], old, "p") == ["demo"]


@pytest.mark.slow   # a pipeline run: the module's smoke_run
def test_rerun_reuses_the_runs_baseline_policies(smoke_run, tmp_path, capsys):
    """experiments/rerun.py: a new run folder with today's code holding a finished run's baseline policies; its
    baselines stage keeps every one (not retrained: the files are untouched) and records what the run recorded."""
    from experiments import rerun
    out = str(tmp_path / "again")
    assert rerun.main([smoke_run, "--state", smoke_run, "--out", out, "--set", "n_test=2"]) == 0
    seed = str(read_json(os.path.join(smoke_run, "manifest.json"))["seed"])
    assert f"python run_all.py --preset smoke --seed {seed} --out" in capsys.readouterr().out
    ckpt = os.path.join(out, "policies", "moe-ramp-d3", "policy.pt")
    stamp = os.stat(ckpt).st_mtime_ns
    assert run_all.main(["--preset", "smoke", "--seed", seed, "--out", out, "--set", "n_test=2", "--only",
                         "baselines", "--workers", "1"]) == 0
    assert os.stat(ckpt).st_mtime_ns == stamp
    assert read_json(os.path.join(out, "stages", "baselines.json"))["result"] == \
        read_json(os.path.join(smoke_run, "stages", "baselines.json"))["result"]
    assert rerun.main([smoke_run, "--state", smoke_run, "--out", out]) == 2   # a rerun starts a new folder


@pytest.mark.slow
def test_ges_screen_runs_a_lever_against_the_runs_own_policies(smoke_run, tmp_path, capsys):
    """experiments/ges_screen.py on a finished run: prepare scores the e2e MLP, the step-matched one and the run's
    GES; a lever (--set) reruns GES from the run's e2e MLPs on the screen's cells, and its table row compares them
    paired, and split gives its specialists' routed designs. The lever 'as run' reproduces the run's own GES scores,
    and pick on it the pick on the run's GES; a lever renamed with other values is refused."""
    from experiments import ges_screen
    work = str(tmp_path / "w")
    assert ges_screen.main(["prepare", smoke_run, "--state", smoke_run, "--ges-runs", smoke_run, "--out", work,
                            "--cells", "obstacle-d2", "--workers", "1"]) == 0
    assert ges_screen.main(["run", work, "--lever", "same", "--workers", "1"]) == 0
    assert ges_screen.main(["run", work, "--lever", "final", "--set", "ges_final_train=true", "--workers", "1"]) == 0
    key = "test-obstacle-d2-ges-obstacle-d2-K3-fps-lloyd"
    assert read_json(os.path.join(work, "same", "scores", f"{key}.json"))["scores"] == \
        read_json(os.path.join(smoke_run, "scores", f"{key}.json"))["scores"]
    ckpt = read_json(os.path.join(work, "final", "ges", "obstacle-d2-K3-fps-lloyd", "state.json"))["ckpt"]
    assert ckpt[0].endswith(f"round{run_all.SMOKE.ges_max_rounds:02d}.ckpt")   # the final training's
    rows = [r.split(" | ") for r in ges_screen.split(work, "final").splitlines()[2:]]   # one row per specialist
    assert [r[2] for r in rows] == ["0", "1", "2"] and sum(int(r[3]) for r in rows) == run_all.SMOKE.n_test
    picked = ges_screen.pick(work, "same", n=2)   # each specialist's policy chosen across its rounds
    assert len(picked["obstacle-d2"]) == 3 and all(0 <= b < run_all.SMOKE.ges_max_rounds for b in picked["obstacle-d2"])
    assert ges_screen.pick(work, "run", n=2) == picked   # the run's own GES (the lever "same" reproduces it)
    assert read_json(os.path.join(work, "scores", f"{key}-picked.json"))["scores"] == \
        read_json(os.path.join(work, "same", "scores", f"{key}-picked.json"))["scores"]
    capsys.readouterr()
    assert ges_screen.main(["run", work, "--lever", "run"]) == 2 and ges_screen.main(["pick", work, "--lever", "x"]) == 2
    # --reuse-round0: the run's round-0 specialists kept as they are (not retrained), the lever acts from round 1;
    # here the run's specialist 1 is given specialist 0's round-0 policy, which no training would reproduce
    os.remove(os.path.join(work, "ges"))
    shutil.copytree(os.path.join(smoke_run, "ges"), os.path.join(work, "ges"))
    ck = os.path.join("ges", "obstacle-d2-K3-fps-lloyd", "ckpt", "spec1_round00.ckpt")
    shutil.copy(os.path.join(work, ck.replace("spec1", "spec0")), os.path.join(work, ck))
    assert ges_screen.main(["run", work, "--lever", "tie", "--set", "probe_tiebreak=true", "--reuse-round0"]) == 0
    assert read_bytes(os.path.join(work, "tie", ck)) == read_bytes(os.path.join(work, ck.replace("spec1", "spec0")))
    assert os.path.exists(os.path.join(work, "tie", "scores", f"{key}.json"))
    assert ges_screen.main(["run", work, "--lever", "x", "--set", "ges_first_round_steps=96", "--reuse-round0"]) == 2
    assert ges_screen.main(["run", work, "--lever", "tie", "--set", "probe_tiebreak=true"]) == 2   # not reused now
    # --matched: a lever with more steps gets its own step-matched e2e MLP at those steps, beside the run's policies
    assert ges_screen.main(["run", work, "--lever", "long", "--set", "ges_round_steps=96", "--reuse-round0",
                            "--matched", "--workers", "1"]) == 0
    p = replace(run_all.SMOKE, ges_round_steps=96)
    warm = ppo.load_checkpoint(os.path.join(work, "policies", "mlp-obstacle-d2", "policy_best.pt"))["steps"]
    own = os.path.join(work, "long", "policies", f"{run_all.MATCHED}-obstacle-d2", "policy.pt")
    assert ppo.load_checkpoint(own)["steps"] >= warm + p.ges_steps(p.ges_max_rounds)
    assert not os.path.exists(os.path.join(work, "policies", f"{run_all.MATCHED}-obstacle-d2", "policy.pt"))
    assert ges_screen.main(["run", work, "--lever", "final", "--set", "probe_tiebreak=true"]) == 2
    assert "name another lever" in capsys.readouterr().err
    # a GES stopped on coverage before its round cap: the table counts the steps of the rounds it ran
    assert ges_screen.main(["run", work, "--lever", "cov", "--set", "ges_target_coverage=0.01", "--reuse-round0",
                            "--workers", "1"]) == 0
    capsys.readouterr()
    assert ges_screen.main(["table", work]) == 0
    rows = [r for r in capsys.readouterr().out.splitlines() if r.startswith("| 3 |")]
    cap = run_all.SMOKE.ges_steps(run_all.SMOKE.ges_trained(run_all.SMOKE.ges_max_rounds))
    assert "ges_target_coverage=0.01" in rows[6] and int(rows[6].split(" | ")[3].replace(",", "")) < cap
    rows = rows[:6]
    assert "run + pick" in rows[0] and "same + pick" in rows[2]
    assert "ges_final_train=true" in rows[3] and "probe_tiebreak=true; round 0 the run's" in rows[4]
    assert "ges_round_steps=96; round 0 the run's; step-matched at its steps" in rows[5]
    assert [r.count("p=") for r in rows] == [4, 3, 3, 4, 4, 4] and rows[1].endswith("| - |")   # `same` not on itself
    final, same = (np.array(read_json(os.path.join(work, lv, "scores", f"{key}.json"))["scores"])
                   for lv in ("final", "same"))
    assert rows[3].endswith(f"| {ges_screen.fmt(rstats.paired_comparison(final, same))} |")   # its own effect
