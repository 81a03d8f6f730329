"""The project's tests, one file grouped by module: ballu.py, ppo.py, ges.py, tpe.py, run_all.py.

Run: pytest -q test_ges.py
"""
import math
from dataclasses import replace

import numpy as np
import pybullet
import pytest

import ballu
from ballu import BASELINE, BalluConfig, BalluEnv

# ==========================================================================================================
# ballu.py: physics sanity, lanes, determinism, curriculum, bad input
# ==========================================================================================================
D_MID = np.array([0.45, 0.45, 0.81, 0.0505])     # centre of D2


def robot_com(env, i=0):
    """Mass-weighted centre of mass of lane i's robot (base + every link's centre of mass) and its mass."""
    p, b = env.p, env.bodies[i]
    ms, xs = [p.getDynamicsInfo(b, -1)[0]], [np.array(p.getBasePositionAndOrientation(b)[0])]
    for link in range(5):
        ms.append(p.getDynamicsInfo(b, link)[0])
        xs.append(np.array(p.getLinkState(b, link)[0]))
    return np.average(xs, axis=0, weights=ms), sum(ms)


def test_mass_matches_facts():
    # ballu_facts.md: total mass 0.198 kg (0.480/0.443), 0.185 kg (0.286/0.215); balloon about 0.095 kg
    for lf, lt, m in ((0.480, 0.443, 0.198), (0.286, 0.215, 0.185)):
        assert ballu.mass_properties([lf, lt, 0.8, 0.01])["total"] == pytest.approx(m, abs=0.0015)
    assert ballu.mass_properties(BASELINE)["balloon"][0] == pytest.approx(0.095, abs=0.001)


@pytest.mark.parametrize("gcr", [0.72, 0.90])
def test_buoyancy_free_fall_accelerates_at_one_minus_gcr_g(gcr):
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


def test_drag_gives_the_terminal_velocity():
    """Falling far from the ground, 0.4 v^2 = (1 - gcr) M g sets the terminal speed (about 1.16 m/s)."""
    gcr = 0.72
    cfg = replace(BalluConfig(), start_z=30.0)
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
    assert f == pytest.approx([-0.4, 1.6, 0.8 * 0.2 * 9.81 + 0.1])


def settle(designs, action, seconds=4.0):
    env = BalluEnv(len(designs))
    env.reset(seed=0, options={"designs": designs, "levels": 0})
    a = np.full((len(designs), 2), action)
    for _ in range(int(seconds / env.cfg.control_dt)):
        env.step(a)
    z = np.array([env.p.getBasePositionAndOrientation(b)[0][2] for b in env.bodies])
    env.close()
    return z


def test_standing_height_grows_with_leg_length():
    z = settle([[0.30, 0.30, 0.8, 0.01], [0.40, 0.40, 0.8, 0.01], [0.50, 0.50, 0.8, 0.01]], 0.0)
    # straight legs (zero action): pelvis near l_f + l_t + 0.068; each step adds 0.2 m of leg
    assert np.all(np.diff(z) > 0.15), z
    assert z[0] == pytest.approx(0.6 + 0.068, abs=0.08)


def test_larger_gcr_settles_higher_on_bent_knees():
    # With the tendon holding the knees bent (a = 0.5), more net weight bends them further:
    # measured 0.844 m (gcr 0.72) vs 0.890 m (gcr 0.90).
    z = settle([[0.45, 0.45, 0.72, 0.001], [0.45, 0.45, 0.90, 0.001]], 0.5)
    assert z[1] > z[0] + 0.02, z


def reference_knee_torque(q, qd, q_star, k):
    """Independent transcription of ballu_facts.md's knee law."""
    spring = -2 * k * (q + math.pi / 4) - 0.001 * qd
    pd = max(0.0, 1.0 * (q_star - q) - 0.08 * qd)
    return float(np.clip(spring + pd, -0.0848, 0.0848))


def test_knee_torque_matches_the_facts_formula():
    pts = [(0.0, 0.0, 0.0, 0.002), (0.5, 0.0, 0.6, 0.002), (0.5, 1.0, 0.6, 0.002), (1.2, -2.0, 0.3, 0.05),
           (0.2, 0.0, 1.7, 0.1), (1.7, 0.0, 0.0, 0.001)]
    for q, qd, qs, k in pts:
        assert ballu.knee_torque(q, qd, qs, k) == pytest.approx(reference_knee_torque(q, qd, qs, k), abs=1e-12)
    rng = np.random.default_rng(0)
    for q, qd, qs, k in zip(rng.uniform(0, 1.75, 500), rng.uniform(-8, 8, 500), rng.uniform(0, 1.75, 500),
                            rng.uniform(0.001, 0.1, 500)):
        tau = ballu.knee_torque(q, qd, qs, k)
        assert abs(tau) <= 0.0848 + 1e-12                                       # the clip holds
        spring = -2 * k * (q + math.pi / 4) - 0.001 * qd
        assert tau >= min(0.0848, max(-0.0848, spring)) - 1e-12                 # the tendon never pushes
        if qs - q - 0.08 * qd <= 0:
            assert tau == pytest.approx(min(0.0848, max(-0.0848, spring)))    # slack tendon: springs only


def test_servo_target_mapping():
    np.testing.assert_allclose(ballu.servo_target([-0.5, 0.25, 1.0, 2.0]), [0, math.pi / 4, math.pi, math.pi])


def rollout(env, actions, seed=0, options=None):
    obs, _ = env.reset(seed=seed, options=options)
    out = [obs]
    for a in actions:
        out.append(env.step(a)[0])
    return np.array(out)


def test_lanes_do_not_interact():
    """Lane 3 alone and lane 3 among 8 robots with other designs follow the same trajectory (to 1e-9)."""
    rng = np.random.default_rng(1)
    T = 80
    designs = np.column_stack([rng.uniform(0.25, 0.55, (8, 2)), rng.uniform(0.72, 0.9, 8), rng.uniform(0.001, 0.1, 8)])
    acts = rng.uniform(-0.2, 1.2, (T, 8, 2))
    batch = BalluEnv(8)
    tb = rollout(batch, acts, options={"designs": designs, "levels": 20})
    alone = BalluEnv(1, lane_ids=[3])
    ta = rollout(alone, acts[:, 3:4], options={"designs": designs[3], "levels": 20})
    batch.close(), alone.close()
    np.testing.assert_allclose(tb[:, 3], ta[:, 0], atol=1e-9)
    assert np.abs(np.diff(tb[:, :, 0], axis=1)).max() > 1e-3   # the lanes did move differently


def d2_sampler(rng, n):
    """Uniform over D2 (module level, so worker processes can unpickle it)."""
    return np.column_stack([np.full((n, 2), 0.45), rng.uniform(0.72, 0.9, n), rng.uniform(0.001, 0.1, n)])


def test_same_seed_same_trajectory_and_workers_do_not_matter():
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


def test_curriculum_rule():
    assert list(ballu.curriculum_update("obstacle", [5, 5, 5, 74, 0], [1.01, 0.7, 0.49, 3.0, -1.0])) == [6, 5, 4, 74, 0]
    assert list(ballu.curriculum_update("ramp", [40, 40, 40], [1.71, 1.5, 1.29])) == [41, 40, 39]
    assert ballu.level_score("obstacle", 28) == pytest.approx(28.1)
    assert ballu.level_score("ramp", 40) == pytest.approx(math.degrees(math.atan(0.801 / 1.5)))


def test_stand_scores_low_and_curriculum_moves_down():
    # `stand` never reaches the obstacle: every episode ends with x < 0.5, 20 levels down from 28.
    s = ballu.score(ballu.stand, [BASELINE, D_MID], "obstacle")
    np.testing.assert_allclose(s, ballu.level_score("obstacle", 8))


def test_episode_limits_and_info():
    cfg = replace(BalluConfig(), episode_steps=5)
    env = BalluEnv(2, cfg)
    env.reset(seed=0, options={"levels": [3, 3]})
    for t in range(5):
        obs, r, term, trunc, info = env.step(np.zeros((2, 2)))
    assert trunc.all() and not term.any() and info["_final_obs"].all()
    assert obs.shape == (2, ballu.OBS_DIM) and np.isfinite(obs).all()
    assert list(info["levels"]) == [2, 2]                       # stood still: x < 0.5, one level down
    # A lane thrown past the height limit ends (terminated, flagged) while the other goes on.
    env.p.resetBasePositionAndOrientation(env.bodies[1], [0, 4.0, 6.0], [0, 0, 0, 1])
    obs, r, term, trunc, info = env.step(np.zeros((2, 2)))
    assert list(term) == [False, True] and info["blowup"][1] and not trunc.any()
    assert np.isfinite(obs).all() and np.isfinite(r).all()
    env.close()


def test_bad_input_raises_clear_errors():
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


def test_dead_worker_gives_a_clear_error():
    env = ballu.VecBallu(2, 2)
    env.reset(seed=0)
    env.procs[1].kill()
    env.procs[1].join()
    with pytest.raises(RuntimeError, match="worker 1 died"):
        env.step(np.zeros((2, 2)))
    env.close()


def test_ramp_terrain_and_toe_height():
    # The ramp surface rises linearly; the obstacle top is flat; both are zero off the terrain.
    assert ballu.surface_height("ramp", np.array([0.4, 1.25, 2.0, 2.1]), 40).tolist() == pytest.approx(
        [0, 0.4005, 0.801, 0])
    assert ballu.surface_height("obstacle", np.array([0.4, 1.0, 1.6]), 30).tolist() == pytest.approx([0, 0.301, 0])
    env = BalluEnv(1, replace(BalluConfig(), task="ramp"))
    obs, _ = env.reset(seed=0, options={"levels": 40})
    assert obs[0, ballu.OBS_NAMES.index("terrain_height")] == pytest.approx(0.801, abs=1e-6)
    env.close()
