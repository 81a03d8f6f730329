"""ballu.py -- a batched PyBullet simulator of BALLU for the GES co-design paper: the robot, its tasks and the score.

Read top to bottom:
  1. the design vector (l_f, l_t, gcr, spcf), Table I, D2/D3 and design samplers -- paper Sec. III-B, Table I
  2. settings (`BalluConfig`)
  3. the robot: mass properties and a URDF generated from a design         -- docs/facts.md "Robot"
  4. the knee law (spring + tendon PD) and the balloon forces              -- facts "Knee", "Buoyancy and drag"
  5. tasks: obstacle and ramp terrain, curriculum, rewards (paper eq. 4)   -- paper Sec. III-C, facts "Tasks"
  6. `BalluEnv`: N robots, one lane each, in PyBullet worlds (one lane per world by default); batched API
  7. `VecBallu`: W worker processes, each a `BalluEnv`, same API (the workers: runkit/lanes.py)
  8. the score J(policy, design) and two scripted controllers (stand, pump)
  9. command line: bench (throughput), strip --out PNG (a pump gait's motion strip): experiments/ballu_bench.py

Of the project it imports only runkit/ (lanes.py: worker processes; box.py: the design box; args.py: its command
line), none of which knows a robot: the learner (ppo.py) and the co-design (ges.py) sit on top. Physics audit and
open-loop capability: experiments/ballu_capability.py.

Equation numbers count the paper's numbered equations in order (eq. 4 = the obstacle reward). Every choice
says where it comes from: [paper], [facts] (the authors' code read as facts, see docs/facts.md), or [ours]
where both are silent, with the study in docs/ that measured it. QUIRKs of the authors' code: options, off.

The batched interface follows Gymnasium's vector-env conventions without importing gymnasium (runkit/lanes.py);
a finished episode is reset in the same step, its last observation in info["final_obs"] (rows: info["_final_obs"]).
"""
from __future__ import annotations

import math
import os
import tempfile
import time
from dataclasses import dataclass, field, replace
from functools import partial
from typing import NamedTuple

import numpy as np

from runkit.box import Box   # names, bounds, the unit cube: one home with ges.py
from runkit.lanes import VecEnv, check_actions, check_split, quiet_stdout, score_lanes, shared_pool  # noqa: F401

with quiet_stdout((1, 2)):   # no "pybullet build time" banner in every script and worker
    import pybullet
    from pybullet_utils import bullet_client

# ----------------------------------------------------------------------------------------------------------
# 1. The design vector and the design spaces (paper Sec. III-B, Table I; facts "Design space")
# ----------------------------------------------------------------------------------------------------------
DESIGN_NAMES = ("l_f", "l_t", "gcr", "spcf")          # the full design vector every lane receives
TABLE_I = {"l_f": (0.25, 0.55), "l_t": (0.25, 0.55), "gcr": (0.72, 0.90), "spcf": (0.001, 0.100)}   # [paper]
TABLE_I_LOW = np.array([TABLE_I[n][0] for n in DESIGN_NAMES])
TABLE_I_HIGH = np.array([TABLE_I[n][1] for n in DESIGN_NAMES])
BASELINE = np.array([0.45, 0.45, 0.70, 0.002])        # [paper] Table I; gcr 0.70 lies OUTSIDE the bounds
D2_CENTRE = np.array([0.45, 0.45, 0.81, 0.0505])      # the centre of D2's Table I box (legs at the baseline's)
# The setups a design space can follow: "table", the paper's text (Table I's box, D2's legs at the baseline's 0.45 m);
# "authors", the configurations their GES experiments ran (docs/facts.md sec. 14): narrower boxes per task, and
# D2 on one robot per task with unequal legs (femur, tibia) [facts]. "l" is the symmetric leg length of D3.
SETUPS = ("table", "authors")
AUTHORS_BOX = {
    "obstacle": {"gcr": (0.75, 0.89), "spcf": (0.001, 0.010), "l": (0.20, 0.48)},
    "ramp": {"gcr": (0.725, 0.89), "spcf": (0.005, 0.100), "l": (0.20, 0.48)},
}
AUTHORS_D2_LEGS = {"obstacle": (0.480, 0.443), "ramp": (0.286, 0.215)}   # (l_f, l_t) of their D2 robots [facts]
SPACE_NAMES = DESIGN_NAMES + ("l",)
# Physical validity (what the simulator can represent at all), wider than any design space. [ours]
VALID_LOW = np.array([0.05, 0.05, 0.0, 0.0])
VALID_HIGH = np.array([1.00, 1.00, 0.99, 1.0])


@dataclass
class DesignSpace(Box):
    """A BALLU design space: a box of free parameters (runkit/box.py: names, lows, highs, the unit cube) plus
    fixed values for the rest of (l_f, l_t, gcr, spcf). The free name "l" means l_f = l_t = l (D3). `full` maps a
    design of the space to the full 4-vector a lane receives. The co-design (ges.py) sees only the box."""
    fixed: dict = field(default_factory=dict)
    task: str | None = None
    setup: str = "table"        # SETUPS: whose box (and D2 robot) this is, named in errors

    def __post_init__(self):
        super().__post_init__()
        self.fixed = {str(n): float(v) for n, v in self.fixed.items()}
        for n in self.names:
            if n not in SPACE_NAMES:
                raise ValueError(f"design parameter name {n!r} not in {SPACE_NAMES}")
        for n in DESIGN_NAMES:  # every full parameter must come from somewhere
            if n not in self.names and n not in self.fixed and not (n in ("l_f", "l_t") and "l" in self.names):
                raise ValueError(f"parameter {n} is neither free nor fixed in this design space")

    def to_dict(self) -> dict:
        return {**super().to_dict(), "fixed": dict(self.fixed), "task": self.task, "setup": self.setup}

    @property
    def label(self) -> str:
        """'obstacle D2 (the authors' box and robot)': the space as an error names it."""
        box = "Table I's box" if self.setup == "table" else "the authors' box and robot"
        return f"{self.task or 'any task'} D{self.d} ({box})"

    def full(self, theta) -> np.ndarray:
        """(n, 4) array of (l_f, l_t, gcr, spcf) (paper Sec. III-B: D2 fixes the legs, D3 ties them)."""
        arr = self.validate(theta)
        cols = []
        for n in DESIGN_NAMES:
            if n in self.names:
                cols.append(arr[:, self.names.index(n)])
            elif n in ("l_f", "l_t") and "l" in self.names:
                cols.append(arr[:, self.names.index("l")])
            else:
                cols.append(np.full(len(arr), self.fixed[n]))
        return np.stack(cols, axis=1)


def _setup(names, task, setup):
    """(lows, highs, fixed legs) of a space's free `names` under `setup` (SETUPS)."""
    if task not in (None, "obstacle", "ramp"):
        raise ValueError(f"task={task!r} not allowed: use None, 'obstacle' or 'ramp'")
    if setup not in SETUPS:
        raise ValueError(f"setup={setup!r} not allowed: use 'table' (paper Table I) or 'authors' (their experiments)")
    if setup == "authors" and task is None:
        raise ValueError("setup='authors' needs task='obstacle' or 'ramp' (the authors' boxes and robots are per task)")
    src = AUTHORS_BOX[task] if setup == "authors" else dict(TABLE_I, l=TABLE_I["l_f"])
    legs = AUTHORS_D2_LEGS[task] if setup == "authors" else tuple(BASELINE[:2])
    return tuple(src[n][0] for n in names), tuple(src[n][1] for n in names), {"l_f": legs[0], "l_t": legs[1]}


def d2(task: str | None = None, setup: str = "table") -> DesignSpace:
    """D2 = (gcr, spcf) on one robot (paper Sec. III-B). setup='table': Table I's box, legs l_f = l_t = 0.45 m
    [paper]; setup='authors': the task's box and D2 robot of the authors' experiments [facts]."""
    lows, highs, legs = _setup(("gcr", "spcf"), task, setup)
    return DesignSpace(("gcr", "spcf"), lows, highs, legs, task, setup)


def d3(task: str | None = None, setup: str = "table") -> DesignSpace:
    """D3 = (gcr, spcf, l) with l_f = l_t = l (paper Sec. III-B). l in Table I's leg range [0.25, 0.55]
    [paper], or the authors' boxes with l in [0.20, 0.48] (setup='authors') [facts]."""
    lows, highs, _ = _setup(("gcr", "spcf", "l"), task, setup)
    return DesignSpace(("gcr", "spcf", "l"), lows, highs, {}, task, setup)


def check_design(design, low=VALID_LOW, high=VALID_HIGH, what="design") -> np.ndarray:
    """Return the design(s) as a float array (n, 4); raise ValueError naming the first bad parameter."""
    d = np.asarray(design, dtype=float)
    if d.ndim == 1:
        d = d[None]
    if d.ndim != 2 or d.shape[1] != 4:
        raise ValueError(f"{what} must have shape (4,) or (n, 4) = {DESIGN_NAMES}, got {np.shape(design)}")
    for j, name in enumerate(DESIGN_NAMES):
        bad = ~np.isfinite(d[:, j]) | (d[:, j] < low[j]) | (d[:, j] > high[j])
        if bad.any():
            v = d[np.argmax(bad), j]
            raise ValueError(f"{what}: {name}={float(v)!r} is outside [{low[j]}, {high[j]}]")
    return d


def normalise_design(design) -> np.ndarray:
    """theta_m of the observation: Table I bounds mapped to [0, 1] (the baseline's gcr gives -0.11). [ours]"""
    return (np.asarray(design, dtype=float) - TABLE_I_LOW) / (TABLE_I_HIGH - TABLE_I_LOW)


# Design samplers: sampler(rng, n) -> (n, 4) full designs for the lanes that reset (training); picklable.
class FixedDesign:
    """Always one design (a per-design policy, e.g. the baseline's)."""

    def __init__(self, design):
        self.design = check_design(design)[0]

    def __call__(self, rng, n):
        return np.tile(self.design, (n, 1))


@dataclass
class UniformDesign:
    """Uniform over a design space (the e2e baselines' design randomisation)."""
    space: DesignSpace

    def __call__(self, rng, n):
        return self.space.full(self.space.sample_uniform(rng, n))


@dataclass
class InSpace:
    """Any sampler over a space's own coordinates (e.g. a GES territory, ges.GaussianSampler) as full designs."""
    space: DesignSpace
    inner: object

    def __call__(self, rng, n):
        return self.space.full(self.inner(rng, n))


# ----------------------------------------------------------------------------------------------------------
# 2. Settings
# ----------------------------------------------------------------------------------------------------------
TASKS = ("obstacle", "ramp")
MAX_LEVEL = 74                                        # [facts] levels 0..74
MAX_LANES_PER_WORLD = 29   # lanes sharing one spot: collision-filter bits 1..29 (bit 0 is the ground plane)
SCORE_START_LEVEL = {"obstacle": 28, "ramp": 40}      # [facts] the score J starts here


def spread_start_levels(task: str, score_start: int | None = None) -> tuple:
    """Lanes that start each at a uniform level in 0..the score's start level (ppo.train's start_level=(low, high))
    [ours]: J sees only levels near its start, a curriculum from 0 climbs a level per episode at most, and failing
    lanes walk down to what the policy can do. Where it is the default: train_start_levels."""
    return (0, SCORE_START_LEVEL[task] if score_start is None else int(score_start))


SPREAD_START_TASKS = ("ramp",)   # [ours] tasks whose training starts spread (train_start_levels)


def train_start_levels(task: str, score_start: int | None = None):
    """A fresh training run's curriculum start: spread (spread_start_levels) on the ramp, level 0 (the facts'
    curriculum) on the obstacle. [ours; the facts start at 0]  The spread start scored higher on the ramp, no
    differently on the obstacle (docs/ppo_protocol; the numbers: docs/choices.md)."""
    return spread_start_levels(task, score_start) if task in SPREAD_START_TASKS else 0


START_LEVEL_NAMES = ("task", "spread", "zero")   # the names a start takes (run_all's ppo_start, ppo_ballu)


def named_start_levels(start, task: str, score_start: int | None = None):
    """A training start, by name or as levels, the one home of the names in START_LEVEL_NAMES: "task"
    (train_start_levels), "spread" (spread_start_levels), "zero" (every lane at level 0); a level L or a
    (low, high) pair is returned as it is."""
    if not isinstance(start, str):
        return start
    if start not in START_LEVEL_NAMES:
        raise ValueError(f"start level name {start!r} must be one of {', '.join(START_LEVEL_NAMES)}")
    if start == "zero":
        return 0
    return (train_start_levels if start == "task" else spread_start_levels)(task, score_start)


HARDWARE_DRAG = 0.4   # [facts] an early branch's balloon drag, an option: drag_coef=HARDWARE_DRAG (docs/facts.md)


@dataclass
class BalluConfig:
    """Everything the simulator needs besides a design. Defaults: [paper] where it says, else [facts]; each [ours]
    names its study, whose numbers are in docs/choices.md ("The measurements behind BalluConfig")."""
    task: str = "obstacle"
    physics_hz: int = 200                 # [paper] Sec. V-A: physics 200 Hz
    decimation: int = 10                  # [paper] control 20 Hz = 10 physics steps per action
    episode_steps: int = 400              # [paper] 20 s episodes
    # densities (kg/m^3) and geometry (m)  [facts]
    rho_limb: float = 198.85
    rho_electronics: float = 7585.7
    rho_balloon: float = 0.4236
    limb_radius: float = 0.005
    pelvis_length: float = 0.15
    hip_y: float = 0.058025
    electronics_length: float = 0.06
    foot_radius: float = 0.004
    foot_offset: float = 0.064            # foot sphere centre past the tibia end
    balloon_radius: float = 0.32
    balloon_height: float = 0.70
    balloon_above_neck: float = 0.38
    neck_xz: tuple = (0.0044, 0.015)
    # knee law  [facts]; the previous robot's 45 deg preload: experiments/ballu_bench.py
    spring_preload: float = math.radians(72.35)   # q0: tau_spring = -2 k (q + q0) - spring_damping qdot
    spring_damping: float = 0.001
    pd_p: float = 1.0
    pd_d: float = 0.08
    tau_max: float = 0.0848               # N m, servo torque limit
    servo_speed: float = 7.48             # rad/s, 60 deg / 0.14 s: clips the D term's knee velocity [facts]
    # [ours, option] a hardware-like servo slewing at <= servo_speed (off: target set at once [facts]); docs/capability
    servo_slew: bool = False
    passive_damping: float = 0.001        # [facts] hips and neck, N m s/rad: a torque -c qdot (URDF damping explodes)
    # [facts] balloon drag -sign(v) drag_coef v^2 per world axis: none, as the authors run their simulation;
    # HARDWARE_DRAG caps how high a high-gcr robot flies (docs/facts.md "Buoyancy and drag", docs/capability)
    drag_coef: float = 0.0
    quirk_buoyancy_torque: bool = False   # QUIRK: the authors' uprighting torque on the balloon (quirk_torque)
    gravity: float = 9.81
    # start pose  [facts]
    start_hip_deg: float = 1.0
    start_knee_deg: float = 27.35
    start_z: float = 1.2
    # friction  [facts]: PyBullet multiplies two bodies' frictions, so the robot gets 1.0 and each surface what
    # PhysX gives its contact with the robot: ground 0.5 x 0.5, box 0.5, ramp (0.8 + 0.5) / 2 (facts "Friction")
    friction_robot: float = 1.0
    friction_ground: float = 0.25
    friction_obstacle: float = 0.5
    friction_ramp: float = 0.65
    # rewards  [paper] eq. 4 [eq:reward_obs] weights; `reward_form` chooses the paper's terms or the authors' code's
    w_nav: float = 5.0
    w_vel: float = 3.0
    w_jump: float = 1.0
    c_jump: float = 1.73
    reward_form: str = "paper"            # "paper": -||g-s||^2 and v_x; "code": the authors' terms (see `reward`)
    # [facts, an option] the authors' warm-up: the first `warmup_steps` control steps of training (`schedule`) hold
    # every lane's level with r_nav off, the next ramp r_nav in (theirs: 100 of 1,500 updates). 0 = off.
    warmup_steps: int = 0
    # [paper / facts] the observation (OBS_FORMS): "paper" = the paper's text plus the task cue and the design;
    # "code" = what the authors' policies observed (pelvis position, knees to the box edge, no angular velocity);
    # "code_vel" [facts + ours, the default] = "code" after the paper's base velocities: the best on both tasks
    # (docs/ppo_protocol, "The authors' MDP").
    obs: str = "code_vel"
    # [ours] reward x control dt, as stock Isaac Lab (the authors' fork: False [facts]); PPO was tuned at it
    reward_dt_scale: bool = True
    # safety limits [facts]: end an episode on non-finite state, pelvis speed > 10 m/s or z > 5 m
    max_speed: float = 10.0
    max_z: float = 5.0
    # [ours] lanes per PyBullet world, all at one spot. One: each world picks its own substeps, so a lane's
    # trajectory never depends on world-mates; as fast as stacking (docs/speed; the sweep: python ballu.py bench).
    lanes_per_world: int = 1
    # [ours, an option] the obstacle curriculum's strict rule: an episode ending short of `up` goes down a level,
    # where the facts' rule keeps the level between `down` and `up` (the stay band: a robot pressed against the box
    # face keeps its level; docs/stay_band). For training envs; `score(strict=)` sets the score's rule.
    strict: bool = False
    # [ours] episodes a training lane keeps a sampled design (the authors: the whole run [facts]); docs/ppo_protocol
    design_hold: int = 1
    # [facts, an option] a lane's first training episode starts at a random step of its 20 s (rsl_rl's
    # init_at_random_ep_len); off, screened without gain (docs/ppo_protocol). `score` plays whole episodes.
    random_first_episode: bool = False
    # [ours, an option] a low-pass filter on the servo command: beta * last applied + (1 - beta) * new (clipped to
    # [0, 1]), observed as the last action; PPO's probabilities stay the Gaussian's (docs/ppo_protocol).
    # beta = exp(-2 pi f / 20 Hz) for a cut-off f: 0.53 at 2 Hz, 0.21 at 5 Hz. 0 = off (the paper's env).
    action_smoothing: float = 0.0
    # [ours, an option] Policies Modulating Trajectory Generators (Iscen et al. 2018): 4 actions pump both knees
    # (`tg_command`; the pump: docs/capability). Off: the paper's two knee commands.
    tg: bool = False
    tg_freq: tuple = (0.5, 5.0)           # Hz for f = 0 .. 1: pump periods of 40 .. 4 control steps
    terrain_width: float = 10.0           # [ours] m across the lane (facts' obstacle 2 m): no walking around it
    solver_iterations: int = 10           # [ours] PyBullet contact solver iterations (measured stable)
    # Stability with the instant knee target [ours] (docs/capability; docs/choices.md):
    # - pelvis_inertia: a floor on the inertia of the pelvis, a 2 g rod spinning freely (passive hips and neck).
    # - substeps: Bullet enforces a joint limit only once a joint is past it, so PyBullet substeps shrink a fast
    #   knee's overshoot (torques and forces held over them): `substeps_fine` in a physics step where some joint
    #   is faster than `fine_speed` or would cross a limit, else `substeps`; equal = a fixed count.
    pelvis_inertia: float = 1e-4
    substeps: int = 4
    substeps_fine: int = 8
    fine_speed: float = 10.0              # rad/s

    @property
    def dt(self) -> float:
        return 1.0 / self.physics_hz

    @property
    def control_dt(self) -> float:
        return self.decimation / self.physics_hz


# ----------------------------------------------------------------------------------------------------------
# 3. The robot: mass properties and URDF
# ----------------------------------------------------------------------------------------------------------
# Link order in the URDF (PyBullet link index = joint index): the root is the pelvis (-1).
NECK, HIP_L, KNEE_L, HIP_R, KNEE_R = 0, 1, 2, 3, 4
BALLOON, FEMUR_L, TIBIA_L, FEMUR_R, TIBIA_R = 0, 1, 2, 3, 4
JOINTS = [NECK, HIP_L, HIP_R, KNEE_L, KNEE_R]    # observation order
JOINT_LIMITS = np.array([[-math.pi / 2, math.pi / 2]] * 3 + [[0.0, math.radians(100)]] * 2)   # JOINTS order [facts]
TIBIAE = [TIBIA_L, TIBIA_R]


def _cyl(m, r, h):
    """Inertia diagonal of a solid cylinder along z."""
    return np.array([m * (3 * r * r + h * h) / 12, m * (3 * r * r + h * h) / 12, m * r * r / 2])


def mass_properties(design, cfg: BalluConfig = BalluConfig()) -> dict:
    """Mass, centre of mass (z in the link frame) and inertia diagonal of each link: mass = volume x density.
    The tibia link carries the tibia cylinder, the electronics cylinder at its end and the foot sphere (one rigid
    body, so no fixed joints cost solver time). [facts]"""
    l_f, l_t = float(design[0]), float(design[1])
    r = cfg.limb_radius
    vol = lambda rad, h: math.pi * rad * rad * h
    out = {}
    m = vol(r, cfg.pelvis_length) * cfg.rho_limb            # pelvis: cylinder along the hip (y) axis
    i = _cyl(m, r, cfg.pelvis_length)
    out["pelvis"] = (m, 0.0, np.array([i[0], i[2], i[0]]))
    m = vol(cfg.balloon_radius, cfg.balloon_height) * cfg.rho_balloon
    out["balloon"] = (m, cfg.balloon_above_neck, _cyl(m, cfg.balloon_radius, cfg.balloon_height))
    m = vol(r, l_f) * cfg.rho_limb
    out["femur"] = (m, -l_f / 2, _cyl(m, r, l_f))
    parts = [  # (mass, com z, inertia about own com)
        (vol(r, l_t) * cfg.rho_limb, -l_t / 2, None),
        (vol(r, cfg.electronics_length) * cfg.rho_electronics, -l_t - cfg.electronics_length / 2, None),
        (4 / 3 * math.pi * cfg.foot_radius ** 3 * cfg.rho_limb, -l_t - cfg.foot_offset, None),
    ]
    inert = [_cyl(parts[0][0], r, l_t), _cyl(parts[1][0], r, cfg.electronics_length),
             np.full(3, 0.4 * parts[2][0] * cfg.foot_radius ** 2)]
    m = sum(p[0] for p in parts)
    com = sum(p[0] * p[1] for p in parts) / m
    i = sum(ii + p[0] * (p[1] - com) ** 2 * np.array([1.0, 1.0, 0.0]) for p, ii in zip(parts, inert))
    out["tibia"] = (m, com, i)
    out["total"] = out["pelvis"][0] + out["balloon"][0] + 2 * (out["femur"][0] + out["tibia"][0])
    return out


def robot_urdf(design, cfg: BalluConfig = BalluConfig()) -> str:
    """URDF text for one design: pelvis root; passive neck and hips; spring/tendon knees (torque driven). No URDF
    joint damping: on these tiny inertias it makes PyBullet explode. [facts]"""
    l_f, l_t = float(design[0]), float(design[1])
    mp_ = mass_properties(design, cfg)
    r = cfg.limb_radius

    def inertial(name):
        m, z, i = mp_[name]
        if name == "pelvis":                    # a floor on the free axle's inertia, see BalluConfig [ours]
            i = np.maximum(i, cfg.pelvis_inertia)
        return (f'<inertial><origin xyz="0 0 {z:.6f}"/><mass value="{m:.8f}"/>'
                f'<inertia ixx="{i[0]:.6e}" iyy="{i[1]:.6e}" izz="{i[2]:.6e}" ixy="0" ixz="0" iyz="0"/>'
                f'</inertial>')

    def cyl(z, rad, h, rpy="0 0 0", rgba="0.15 0.15 0.15 1"):
        g = f'<geometry><cylinder radius="{rad}" length="{h:.6f}"/></geometry>'
        o = f'<origin xyz="0 0 {z:.6f}" rpy="{rpy}"/>'
        return (f'<visual>{o}{g}<material name="c{rgba}"><color rgba="{rgba}"/></material></visual>'
                f"<collision>{o}{g}</collision>")

    def sphere(z, rad):
        g = f'<geometry><sphere radius="{rad}"/></geometry>'
        o = f'<origin xyz="0 0 {z:.6f}"/>'
        return f"<visual>{o}{g}</visual><collision>{o}{g}</collision>"

    def joint(name, parent, child, xyz, lo, hi):
        return (f'<joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
                f'<origin xyz="{xyz}"/><axis xyz="0 1 0"/>'
                f'<limit lower="{lo:.6f}" upper="{hi:.6f}" effort="100" velocity="100"/></joint>')

    h90 = math.pi / 2
    links = [f'<link name="pelvis">{inertial("pelvis")}{cyl(0, r, cfg.pelvis_length, f"{h90} 0 0")}</link>',
             f'<link name="balloon">{inertial("balloon")}'
             f'{cyl(cfg.balloon_above_neck, cfg.balloon_radius, cfg.balloon_height, rgba="0.75 0.85 1 1")}</link>']
    joints = [joint("neck", "pelvis", "balloon", f"{cfg.neck_xz[0]} 0 {cfg.neck_xz[1]}", -h90, h90)]
    for side, y in (("l", cfg.hip_y), ("r", -cfg.hip_y)):
        links.append(f'<link name="femur_{side}">{inertial("femur")}{cyl(-l_f / 2, r, l_f)}</link>')
        tib = (cyl(-l_t / 2, r, l_t) + cyl(-l_t - cfg.electronics_length / 2, r, cfg.electronics_length, rgba="0.8 0.1 0.1 1")
               + sphere(-l_t - cfg.foot_offset, cfg.foot_radius))
        links.append(f'<link name="tibia_{side}">{inertial("tibia")}{tib}</link>')
        joints.append(joint(f"hip_{side}", "pelvis", f"femur_{side}", f"0 {y} 0", -h90, h90))
        joints.append(joint(f"knee_{side}", f"femur_{side}", f"tibia_{side}", f"0 0 {-l_f:.6f}",
                            0.0, math.radians(100)))
    return '<?xml version="1.0"?><robot name="ballu">' + "".join(links) + "".join(joints) + "</robot>"


# ----------------------------------------------------------------------------------------------------------
# 4. The knee law and the balloon forces (applied every physics step)
# ----------------------------------------------------------------------------------------------------------
def servo_target(action):
    """Action -> servo angle target m = clip(pi a, 0, pi). [facts]"""
    return np.clip(math.pi * np.asarray(action, dtype=float), 0.0, math.pi)


def knee_torque(q: float, qdot: float, q_star: float, spcf: float, cfg: BalluConfig = BalluConfig()) -> float:
    """Knee torque of two springs (toward a straight leg) plus a tendon that can only pull. [facts]
    tau_spring = -2 k (q + q0) - 0.001 qdot (q0 = 72.35 deg);  tau_pd = max(0, 1.0 (q* - q) + 0.08 clip(-qdot, -7.48, 7.48));
    tau = clip(tau_spring + tau_pd, -0.0848, 0.0848): the D term sees the knee velocity clipped to the servo's
    speed [facts]. Plain floats: it runs per knee per physics step."""
    v = cfg.servo_speed
    tau_spring = -2.0 * spcf * (q + cfg.spring_preload) - cfg.spring_damping * qdot
    tau_pd = max(0.0, cfg.pd_p * (q_star - q) + cfg.pd_d * min(v, max(-v, -qdot)))
    return min(cfg.tau_max, max(-cfg.tau_max, tau_spring + tau_pd))


def balloon_force(gcr: float, mass: float, vel, cfg: BalluConfig = BalluConfig()) -> list:
    """Buoyancy gcr*M*g straight up plus drag -sign(v) c v^2 per world axis (c = cfg.drag_coef: 0 by default,
    HARDWARE_DRAG as an option), at the balloon centre. [facts]"""
    c = cfg.drag_coef
    vx, vy, vz = vel
    return [-c * vx * abs(vx), -c * vy * abs(vy), gcr * mass * cfg.gravity - c * vz * abs(vz)]


def quirk_torque(balloon_orn, force, cfg: BalluConfig = BalluConfig()) -> list:
    """QUIRK of the authors' code: torque r x F, r = 0.38 m along the balloon's own axis (rotating with it): lift
    acts as if 0.76 m above the neck, turning a tilted balloon upright. Off (`quirk_buoyancy_torque`). [facts]"""
    rx, ry, rz = cfg.balloon_above_neck * z_axis(balloon_orn)   # R (0, 0, r)
    fx, fy, fz = force
    return [ry * fz - rz * fy, rz * fx - rx * fz, rx * fy - ry * fx]


# ----------------------------------------------------------------------------------------------------------
# 5. Tasks: terrain, curriculum and rewards
# ----------------------------------------------------------------------------------------------------------
def task_geometry(task: str) -> dict:
    """Terrain start/end, goal x and curriculum thresholds on the final pelvis x. [facts]"""
    if task == "obstacle":
        return dict(x0=0.5, x1=1.5, goal=2.0, up=1.0, down=0.5)
    if task == "ramp":
        return dict(x0=0.5, x1=2.0, goal=2.5, up=1.70, down=1.295)
    raise ValueError(f"task={task!r} is not one of {TASKS}")


def level_height(task: str, level):
    """Obstacle height (1 cm per level) or ramp top height (grade +1.33 % per level), metres. [facts]"""
    return 0.001 + (0.01 if task == "obstacle" else 0.02) * np.asarray(level)


def level_score(task: str, level):
    """Curriculum level -> the score's unit: obstacle height in cm, ramp angle in degrees. [facts]"""
    h = level_height(task, level)
    return 100.0 * h if task == "obstacle" else np.degrees(np.arctan(h / 1.5))


def curriculum_update(task: str, level, final_x, step=1, strict: bool = False):
    """Up one level past `up`, down one short of `down`, clipped to 0..74 [facts]; between the two (the stay band)
    the level stays. `strict` [ours, obstacle only]: down one short of `up`, so only clearing keeps a level.
    `step` (a scalar or one per lane) moves that many levels instead: score's bisection schedule (`level_steps`)
    uses it. [ours]"""
    g, x = task_geometry(check_strict(task, strict)), np.asarray(final_x)
    up = x > g["up"]
    move = up.astype(np.int64) - (~up if strict else x < g["down"])
    return np.clip(np.asarray(level) + np.asarray(step) * move, 0, MAX_LEVEL)


def check_strict(task: str, strict) -> str:
    """The strict rule is the obstacle's: its band is a robot at the box, where the ramp's is a robot on the slope."""
    if not isinstance(strict, (bool, np.bool_)) or (strict and task != "obstacle"):
        raise ValueError(f"strict={strict!r} for task={task!r}: True only for the obstacle (its stay band ends "
                         f"at the box face), else False")
    return task


OUTCOMES = ("short", "band", "cleared")   # where an episode ends against the curriculum's thresholds


def episode_outcome(task: str, final_x) -> np.ndarray:
    """Each episode's end as an index of OUTCOMES: 0 short of `down`, 1 in the stay band between `down` and `up`
    (the facts' rule keeps the level), 2 past `up` (obstacle: cleared the box); -1 a blown-up episode (NaN x)."""
    g, x = task_geometry(task), np.asarray(final_x, dtype=float)
    out = np.where(x > g["up"], 2, np.where(x < g["down"], 0, 1))
    return np.where(np.isfinite(x), out, -1)


def surface_height(task: str, x, level):
    """Height of the terrain under world x in a lane (0 off the obstacle / ramp)."""
    g, h = task_geometry(task), level_height(task, level)
    on = (x >= g["x0"]) & (x <= g["x1"])
    if task == "obstacle":
        return np.where(on, h, 0.0)
    return np.where(on, h * (x - g["x0"]) / (g["x1"] - g["x0"]), 0.0)


FOOT_POINT_BELOW_TIBIA = 0.034   # [facts] the code reward's foot point: 3.4 cm down the electronics cylinder


def reward(task, cfg: BalluConfig, s: LaneState, levels, l_t, nav_scale=1.0):
    """Obstacle: w1 r_nav + w2 r_vel + w3 (e^{c z_toe} - 1) [paper eq. 4]; ramp: w1 r_nav + w2 r_vel.
    reward_form="paper" (default): r_nav = -||g - s||^2 with s the pelvis in the ground plane, r_vel = v_x (the
    pelvis velocity along world x, toward the goal [ours]: the pelvis spins freely, so its own x axis is no
    heading), z_toe the lower foot tip's height above the terrain under it.
    reward_form="code" [facts], the authors' terms where they measure them: r_nav = max(0, 1 - 0.33 d)
    (ramp: max(-2, 1 - 0.40 d)) with d from the goal to the mean ground-plane position of the two tibia ends
    (their servo horns); r_vel = v_x capped (0 above 0.8 m/s, e^v - 1 below 0); z_toe the lower of the two
    points FOOT_POINT_BELOW_TIBIA below the tibia ends, less the box height only while both lie over the box,
    the jump term 0 above 1.8 m. `nav_scale` multiplies r_nav (the warm-up, BalluConfig.warmup_steps); `l_t`
    is each lane's tibia length."""
    goal, x, vx = task_geometry(task)["goal"], s.pos[:, 0], s.vel[:, 0]
    if cfg.reward_form == "paper":
        dist2 = (goal - x) ** 2 + s.pos[:, 1] ** 2   # every lane runs along y = 0
        r_nav, r_vel = -dist2, vx
        toe = s.toe
        clearance = (toe[:, :, 2] - surface_height(task, toe[:, :, 0], np.asarray(levels)[:, None])).min(axis=1)
        jump = np.expm1(cfg.c_jump * clearance)
    elif cfg.reward_form == "code":
        ends = s.knee - np.asarray(l_t)[:, None, None] * s.leg_axis        # tibia ends (n, 2, 3)
        mid = ends[:, :, :2].mean(axis=1)
        d = np.hypot(goal - mid[:, 0], mid[:, 1])
        r_nav = np.maximum(0.0, 1.0 - 0.33 * d) if task == "obstacle" else np.maximum(-2.0, 1.0 - 0.40 * d)
        r_vel = np.where(vx > 0.8, 0.0, np.where(vx < 0, np.expm1(np.minimum(vx, 0.0)), vx))
        feet = ends - FOOT_POINT_BELOW_TIBIA * s.leg_axis
        g = task_geometry(task)
        over = ((feet[:, :, 0] >= g["x0"]) & (feet[:, :, 0] <= g["x1"])).all(axis=1)
        z = feet[:, :, 2].min(axis=1) - np.where(over, level_height(task, levels), 0.0)
        jump = np.where(z > 1.8, 0.0, np.expm1(cfg.c_jump * np.minimum(z, 1.8)))
    else:
        raise ValueError(f"reward_form={cfg.reward_form!r} is not one of ('paper', 'code')")
    r = cfg.w_nav * nav_scale * r_nav + cfg.w_vel * r_vel
    if task == "obstacle":
        r = r + cfg.w_jump * jump
    return r * (cfg.control_dt if cfg.reward_dt_scale else 1.0)


def tg_command(a, phase, cfg: BalluConfig):
    """The trajectory generator (cfg.tg) [ours]: actions (c_l, c_r, f, A) and the phases (cycles) of their lanes
    -> the knee commands c_k + 0.5 A sin(2 pi phase) (A, f and the result clipped to [0, 1]) and the phases
    advanced at tg_freq[0] + f (tg_freq[1] - tg_freq[0]) Hz. A mean action 0.5 starts a 2.75 Hz half pump."""
    lo, hi = cfg.tg_freq
    phase = (phase + (lo + (hi - lo) * np.clip(a[:, 2], 0, 1)) * cfg.control_dt) % 1.0
    swing = 0.5 * np.clip(a[:, 3], 0, 1) * np.sin(2 * np.pi * phase)
    return np.clip(a[:, :2] + swing[:, None], 0.0, 1.0), phase


class LaneState(NamedTuple):
    """What BalluEnv.read_lanes() reads of every lane after a step, in world coordinates (each lane's frame):
    pelvis position (n, 3) and orientation (n, 4: x, y, z, w), pelvis linear and angular velocity (n, 6),
    joint positions and velocities (n, 5, JOINTS order), and per leg (n, 2, 3): the foot's tip, the knee (the
    tibia frame's origin) and the unit vector from the foot up the tibia."""
    pos: np.ndarray
    vel: np.ndarray
    jq: np.ndarray
    jqd: np.ndarray
    toe: np.ndarray
    orn: np.ndarray
    knee: np.ndarray
    leg_axis: np.ndarray


def z_axis(quat) -> np.ndarray:
    """The third column of the rotation of unit quaternions quat (..., 4) = (x, y, z, w): R (0, 0, 1), where a
    body's own z axis points (a leg's, the balloon's)."""
    x, y, z, w = np.moveaxis(np.asarray(quat, dtype=float), -1, 0)
    return np.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], axis=-1)


def to_base_frame(quat, v):
    """World vectors v (n, 3) expressed in the frames of the unit quaternions quat (n, 4) = (x, y, z, w): R^T v."""
    q, w = quat[:, :3], quat[:, 3:]
    t = 2.0 * np.cross(q, v)            # R^T v = v - w t + q x t for the conjugate rotation
    return v - w * t + np.cross(q, t)


# ----------------------------------------------------------------------------------------------------------
# 6. BalluEnv: N robots, one lane each, in PyBullet worlds (one lane per world by default)
# ----------------------------------------------------------------------------------------------------------
_JOINT_NAMES = ("neck", "hip_l", "hip_r", "knee_l", "knee_r")
# The observation's blocks, each a list of entry names; a form (BalluConfig.obs) lists the blocks in order.
OBS_BLOCKS = {
    "base_vel": ["vx", "vy", "vz", "wx", "wy", "wz"],   # pelvis velocity in its own frame, as Isaac Lab reports it
    "base_lin_vel": ["vx", "vy", "vz"],
    "joint_pos": [f"q_{j}" for j in _JOINT_NAMES],
    "joint_vel": [f"qd_{j}" for j in _JOINT_NAMES],
    "last_action": ["a_l", "a_r"],
    "tg": ["tg_sin", "tg_cos"],                          # the trajectory generator's phase (BalluConfig.tg only)
    "cue": ["dist_to_terrain", "terrain_height"],        # x0 - pelvis x, the level's box / ramp height
    "pelvis_pos": ["x", "y", "z"],                       # pelvis position in the lane's frame
    "knee_to_edge": ["knee_l_to_edge", "knee_r_to_edge"],   # x0 - x of each tibia frame origin (the knee)
    "design": [f"design_{n}" for n in DESIGN_NAMES],     # normalised design, last: the MoE's gate reads it there
}
# [paper] Sec. III-C's state plus the task cue [facts]; [facts] what the authors' policies observed, per task,
# leaving out their constant goal input and the two servo-horn joints our robot does not model (docs/facts.md).
OBS_FORMS = {
    "paper": {t: ["base_vel", "joint_pos", "joint_vel", "last_action", "tg", "cue", "design"] for t in TASKS},
    "code": {"obstacle": ["joint_pos", "joint_vel", "cue", "pelvis_pos", "knee_to_edge", "last_action", "tg",
                          "design"],
             "ramp": ["joint_pos", "joint_vel", "pelvis_pos", "base_lin_vel", "last_action", "tg", "design"]},
    "code_vel": {"obstacle": ["base_vel", "joint_pos", "joint_vel", "cue", "pelvis_pos", "knee_to_edge",
                              "last_action", "tg", "design"],
                 "ramp": ["base_vel", "joint_pos", "joint_vel", "pelvis_pos", "last_action", "tg", "design"]},
}


def obs_blocks(cfg: BalluConfig) -> list:
    """The blocks of the observation under cfg, in order (the trajectory generator's phase only with cfg.tg)."""
    if cfg.obs not in OBS_FORMS:
        raise ValueError(f"obs={cfg.obs!r} is not one of {tuple(OBS_FORMS)}")
    return [b for b in OBS_FORMS[cfg.obs][cfg.task] if b != "tg" or cfg.tg]


def obs_names(cfg: BalluConfig) -> tuple:
    """The name of every observation entry under cfg, in order: a checkpoint keeps them (ppo.py), so a policy
    cannot be run on an env that observes something else."""
    return tuple(n for b in obs_blocks(cfg) for n in OBS_BLOCKS[b])


def obs_config(names, task: str = "obstacle") -> BalluConfig:
    """The BalluConfig (obs form, tg) whose observation has these entry names on `task`: what a checkpoint
    that keeps its names (ppo.py) runs on. None = the paper's observation (older checkpoints)."""
    for form in OBS_FORMS:
        for tg in (False, True):
            cfg = BalluConfig(task=task, obs=form, tg=tg)
            if names is None or tuple(names) == obs_names(cfg):
                return cfg
    raise ValueError(f"no observation form gives the entries {tuple(names)} on task {task!r}")


def policy_config(policy, task: str, cfg: BalluConfig | None = None) -> BalluConfig:
    """The BalluConfig a policy plays `task` on: `cfg` if given, else the observation it trained with (its entries'
    names, ppo.PolicyFn.obs_names; a checkpoint older than the names observed the paper's form), else the default.
    A policy that observed other entries than cfg gives is a clear error, by name (or count, without names)."""
    if cfg is None:
        cfg = obs_config(policy.obs_names, task) if hasattr(policy, "obs_names") else BalluConfig()
    cfg = replace(cfg, task=task)
    seen, size, gives = getattr(policy, "obs_names", None), getattr(policy, "obs_dim", None), obs_names(cfg)
    if (seen is not None and tuple(seen) != gives) or (seen is None and size is not None and size != len(gives)):
        what = f"{len(seen)} entries {tuple(seen)}" if seen is not None else f"{size} entries (names not kept)"
        raise ValueError(f"the policy observed {what}, this env (obs={cfg.obs!r}, task={task!r}) gives {gives}: "
                         f"play it with the BalluConfig it trained with (ballu.obs_config of its names)")
    return cfg


OBS_NAMES = list(obs_names(BalluConfig()))                       # the default observation (obstacle)
OBS_DIM, ACT_DIM = len(OBS_NAMES), 2


def dims(cfg: BalluConfig) -> tuple:
    """(obs_dim, act_dim) of the env under cfg: 4 actions with the trajectory generator (cfg.tg), else 2."""
    return len(obs_names(cfg)), (4 if cfg.tg else ACT_DIM)


def bullet_substeps(n: int) -> int:
    """PyBullet's numSubSteps for n substeps per physics step: 0 for one (Bullet's plain step, without its
    fixed-step accumulator)."""
    return n if n > 1 else 0


_LIMITS = tuple(map(tuple, JOINT_LIMITS.tolist()))   # plain floats for the per-step check below


def needs_fine_substeps(joint_states, dt: float, speed: float) -> bool:
    """Adaptive substeps [ours]: True if some joint (JOINTS order, PyBullet joint states) moves faster than
    `speed` rad/s or would cross a limit within dt at its present speed (BalluConfig.substeps)."""
    for (lo, hi), st in zip(_LIMITS, joint_states):
        q, qd = st[0], st[1]
        if qd > speed or qd < -speed or not lo <= q + qd * dt <= hi:
            return True
    return False


class _World:
    """One PyBullet world (a DIRECT client): ground plane, shared terrain shapes, and up to
    `cfg.lanes_per_world` lanes stacked at the same spot, each with its own collision-filter bit. It builds,
    moves and loads its lanes' bodies; BalluEnv keeps their ids."""

    def __init__(self, cfg: BalluConfig):
        with quiet_stdout():   # PyBullet's C code prints "argv[0]=" on every connect
            self.p = bullet_client.BulletClient(connection_mode=pybullet.DIRECT)
        p, self.cid, self.lanes, self.cfg = self.p, self.p._client, [], cfg
        p.setGravity(0, 0, -cfg.gravity)
        p.setPhysicsEngineParameter(fixedTimeStep=cfg.dt, numSubSteps=bullet_substeps(cfg.substeps),
                                    numSolverIterations=cfg.solver_iterations,
                                    deterministicOverlappingPairs=1)
        self.substeps = cfg.substeps          # the substeps stepSimulation takes now (see _physics_step)
        self.plane = p.createMultiBody(0, p.createCollisionShape(p.GEOM_PLANE))
        p.changeDynamics(self.plane, -1, lateralFriction=cfg.friction_ground)
        p.setCollisionFilterGroupMask(self.plane, -1, 1, 0x3FFFFFFF)
        half = [0.5, cfg.terrain_width / 2, 0.5]
        self.box_shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=half)
        self.box_visual = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=[0.6, 0.45, 0.3, 1])
        self.ramp_shapes = {}

    def place_terrain(self, body: int, level: int, bit: int) -> int:
        """A lane's terrain at `level` (body -1: none yet), touching collision bit `bit` only: the obstacle box
        is moved, a ramp wedge rebuilt. Returns its body id."""
        cfg, p = self.cfg, self.p
        h = float(level_height(cfg.task, level))
        if cfg.task == "obstacle":
            if body >= 0:
                p.resetBasePositionAndOrientation(body, [1.0, 0, h - 0.5], [0, 0, 0, 1])
                return body
            body = p.createMultiBody(0, self.box_shape, self.box_visual, basePosition=[1.0, 0, h - 0.5])
            friction = cfg.friction_obstacle
        else:
            if level not in self.ramp_shapes:   # a wedge rising from x=0.5 to 2.0, then a vertical drop
                w = cfg.terrain_width / 2
                v = [[0.5, -w, 0], [2.0, -w, 0], [2.0, -w, h], [0.5, w, 0], [2.0, w, 0], [2.0, w, h]]
                tri = [0, 1, 2, 3, 5, 4, 0, 3, 4, 0, 4, 1, 1, 4, 5, 1, 5, 2, 0, 2, 5, 0, 5, 3]
                self.ramp_shapes[level] = (p.createCollisionShape(p.GEOM_MESH, vertices=v),
                                           p.createVisualShape(p.GEOM_MESH, vertices=v, indices=tri,
                                                               rgbaColor=[0.6, 0.45, 0.3, 1]))
            if body >= 0:
                p.removeBody(body)
            body = p.createMultiBody(0, *self.ramp_shapes[level], basePosition=[0, 0, 0])
            friction = cfg.friction_ramp
        p.changeDynamics(body, -1, lateralFriction=friction)
        p.setCollisionFilterGroupMask(body, -1, bit, bit)
        return body

    def load_robot(self, body: int, urdf_path: str, bit: int) -> int:
        """A robot loaded from `urdf_path` in place of `body` (-1: none yet), its id: the robot's friction, no
        PyBullet damping [facts: passive_damping], collisions with ground and bit `bit`, velocity motors off."""
        cfg, p = self.cfg, self.p
        if body >= 0:
            p.removeBody(body)
        b = p.loadURDF(urdf_path, [0, 0, cfg.start_z], flags=p.URDF_USE_INERTIA_FROM_FILE)
        for link in range(-1, 5):
            p.changeDynamics(b, link, lateralFriction=cfg.friction_robot, linearDamping=0.0, angularDamping=0.0,
                             jointDamping=0.0)
            p.setCollisionFilterGroupMask(b, link, bit, 1 | bit)
        p.setJointMotorControlArray(b, JOINTS, p.VELOCITY_CONTROL, forces=[0.0] * 5)
        return b

    def reset_robot(self, body: int):
        """A robot back at its start pose, at rest. [facts]"""
        cfg, p = self.cfg, self.p
        hip, knee = math.radians(cfg.start_hip_deg), math.radians(cfg.start_knee_deg)
        p.resetBasePositionAndOrientation(body, [0, 0, cfg.start_z], [0, 0, 0, 1])
        p.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0])
        for j, q in ((NECK, 0.0), (HIP_L, hip), (HIP_R, hip), (KNEE_L, knee), (KNEE_R, knee)):
            p.resetJointState(body, j, q, 0.0)


def check_config(cfg: BalluConfig):
    """A clear error for settings the simulator cannot run (names the field and its allowed range)."""
    if not 1 <= cfg.lanes_per_world <= MAX_LANES_PER_WORLD:
        raise ValueError(f"lanes_per_world={cfg.lanes_per_world!r} must lie in [1, {MAX_LANES_PER_WORLD}]")
    for name, top in (("substeps", 64), ("substeps_fine", 64), ("design_hold", 10 ** 6)):
        v = getattr(cfg, name)
        if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or not 1 <= v <= top:
            raise ValueError(f"{name}={v!r} must be an integer in [1, {top}]")
    if cfg.substeps_fine < cfg.substeps:
        raise ValueError(f"substeps_fine={cfg.substeps_fine} must be >= substeps={cfg.substeps}")
    lo, hi = cfg.tg_freq
    if not 0 < lo < hi < math.inf:
        raise ValueError(f"tg_freq={cfg.tg_freq!r} must be (low, high) Hz with 0 < low < high")
    if not 0 <= cfg.action_smoothing < 1:   # (NaN fails too)
        raise ValueError(f"action_smoothing={cfg.action_smoothing!r} must lie in [0, 1)")
    if cfg.obs not in OBS_FORMS:
        raise ValueError(f"obs={cfg.obs!r} is not one of {tuple(OBS_FORMS)}")
    check_strict(cfg.task, cfg.strict)
    if cfg.reward_form not in ("paper", "code"):
        raise ValueError(f"reward_form={cfg.reward_form!r} is not one of ('paper', 'code')")
    if not isinstance(cfg.warmup_steps, (int, np.integer)) or isinstance(cfg.warmup_steps, bool) \
            or cfg.warmup_steps < 0:
        raise ValueError(f"warmup_steps={cfg.warmup_steps!r} must be an integer >= 0")
    for name in ("drag_coef", "passive_damping", "fine_speed"):
        v = getattr(cfg, name)
        if not (isinstance(v, (int, float)) and 0 <= v < math.inf):
            raise ValueError(f"{name}={v!r} must be a finite number >= 0")
    task_geometry(cfg.task)


class _ExactResume:
    """BalluEnv's saved state: ppo.train keeps it in its checkpoints, so a killed run goes on exactly as if it
    had never stopped. Mixed into BalluEnv (below), whose lanes it saves and restores."""

    def get_state(self) -> list | None:
        """What each lane needs to go on exactly from here, in plain types (a torch checkpoint loads them with
        weights_only; the actions as float64 bytes): its design, level, clock, random stream and its episode's
        actions so far. [ours] Not PyBullet's saveState, which does not restore contacts exactly (docs/ppo_protocol
        "Resumed runs"): an episode depends on nothing before its start (the robot is dropped from start_z), so
        set_state replays the episode (test: bit for bit). None where lanes share worlds (lanes_per_world > 1)."""
        if self.cfg.lanes_per_world != 1:
            return None
        return [{"id": int(self.lane_ids[i]), "design": self.designs[i].tolist(), "level": int(self.levels[i]),
                 "t": int(self.t[i]), "ep_return": float(self.ep_return[i]), "held": int(self._held[i]),
                 "rng": self.rngs[i].bit_generator.state,
                 "actions": np.asarray(self._ep_actions[i], dtype=np.float64).tobytes()}
                for i in range(self.num_envs)]

    def set_state(self, lanes: list):
        """Go on from get_state()'s output: each lane's robot is put at its episode's start and its actions
        replayed. The env must hold the same lane ids, one per world (ValueError otherwise)."""
        ids = [int(k) for k in self.lane_ids]
        if [lane["id"] for lane in lanes] != ids or self.cfg.lanes_per_world != 1:
            raise ValueError(f"saved lanes {[lane['id'] for lane in lanes]} do not match this env's lanes {ids} "
                             f"(lanes_per_world={self.cfg.lanes_per_world}, must be 1)")
        for i, lane in enumerate(lanes):
            self.designs[i], self.levels[i] = lane["design"], lane["level"]
            self._set_terrain(i, lane["level"])
            self._load_robot(i, self.designs[i])
            self.tg_phase[i] = 0.0
        actions = [np.frombuffer(lane["actions"], dtype=np.float64).reshape(-1, self.act_dim).tolist()
                   for lane in lanes]
        self._replay(actions)
        for i, lane in enumerate(lanes):
            self.t[i], self.ep_return[i], self._held[i] = lane["t"], lane["ep_return"], lane["held"]
            self.rngs[i] = np.random.default_rng(0)
            self.rngs[i].bit_generator.state = lane["rng"]
            self._ep_actions[i] = actions[i]
        self._ready = True

    def _replay(self, actions: list):
        """Step lane i through actions[i] from its episode's start, the lanes in lock-step aligned at their ends:
        a lane's world steps only over its own actions. The benchmark's counters are left as they were."""
        counters = self.sim_seconds, self.world_steps, self.fine_steps
        T = max(map(len, actions), default=0)
        for k in range(T):
            lanes = np.array([i for i, acts in enumerate(actions) if k >= T - len(acts)])
            self._command(np.array([actions[i][k - T + len(actions[i])] for i in lanes], dtype=float), lanes)
            self._stepping = [self._world[i] for i in lanes]
            for _ in range(self.cfg.decimation):
                self._physics_step()
        self._stepping = self.worlds
        self.sim_seconds, self.world_steps, self.fine_steps = counters


class BalluEnv(_ExactResume):
    """N BALLU robots, one lane each, stepped together in PyBullet worlds (DIRECT mode, no GUI) of
    `cfg.lanes_per_world` lanes (one by default), which lie on top of each other at y = 0, each with its own
    terrain body and collision-filter bit, so a robot touches only the ground and its own terrain: a lane offset
    sideways would round its contacts differently, and this chaotic system turns rounding into different
    trajectories. Each lane has its own design, curriculum level and random generator (seeded from (seed, lane
    id)). Reset lanes draw designs from `design_sampler(rng, n) -> (n, 4)` if one is set (training: every
    `cfg.design_hold` episodes and at every full reset), else keep theirs (scoring). With `curriculum=True` each
    finished episode moves the lane's level. Read as reset, step, observe, physics; get_state and set_state
    (exact resume of a killed training) are _ExactResume's."""

    def __init__(self, num_envs: int = 1, cfg: BalluConfig = BalluConfig(), lane_ids=None,
                 curriculum: bool = True, design_sampler=None):
        if not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs={num_envs!r} must be an integer >= 1")
        check_config(cfg)
        self.cfg, self.num_envs, self.curriculum = cfg, int(num_envs), curriculum
        self.design_sampler = design_sampler
        self.lane_ids = np.arange(num_envs) if lane_ids is None else np.asarray(lane_ids)
        self.obs_dim, self.act_dim = dims(cfg)
        self.obs_names = obs_names(cfg)   # kept in a checkpoint: a policy runs only on what it observed
        n, B = self.num_envs, cfg.lanes_per_world
        self.worlds = [_World(cfg) for _ in range(-(-n // B))]
        self._world = [self.worlds[i // B] for i in range(n)]   # lane i -> its world
        for i in range(n):
            self._world[i].lanes.append(i)
        self._tmp = tempfile.TemporaryDirectory(prefix="ballu_urdf_")
        self.designs = np.tile(BASELINE, (n, 1))
        self.levels = np.zeros(n, dtype=np.int64)
        self.level_step = 1              # levels a finished episode moves (score sets one per lane to bisect)
        self.bodies, self.terrain = [-1] * n, [-1] * n   # each lane's robot and terrain body in its world
        self._terrain_level = np.full(n, -1)
        self._body_design = [None] * n
        # per-lane state of the hot loop as plain Python floats (see _physics_step)
        self._servo = [[0.0, 0.0] for _ in range(n)]        # servo horn angle m (rad)
        self._servo_goal = [[0.0, 0.0] for _ in range(n)]
        self.monitor = None              # optional callable(env) after every physics step (the audit uses it)
        self._applied = [None] * n       # (knee torques, balloon force) of the last step, kept for the monitor
        self._mass, self._gcr, self._spcf = [0.0] * n, [0.0] * n, [0.0] * n
        self._toe_len = np.zeros(n)      # knee to the foot's tip (m)
        self.last_action = np.zeros((n, 2))
        self.tg_phase = np.zeros(n)      # cycles of the trajectory generator (cfg.tg)
        self.t, self.ep_return = np.zeros(n, dtype=np.int64), np.zeros(n)   # each lane's clock and return
        self._held = np.zeros(n, dtype=np.int64)   # episodes a lane has begun on its sampled design
        self._ep_actions = [[] for _ in range(n)]   # each lane's actions in its episode so far (get_state)
        self.rngs = [np.random.default_rng(0) for _ in range(n)]
        self._ready, self.sim_seconds = False, 0.0   # sim_seconds: stepSimulation's own time (the benchmark)
        self.world_steps, self.fine_steps = 0, 0   # world physics steps, and those with fine substeps
        self.train_steps = None          # the trainer's steps so far, if it tells them (schedule)
        self._stepping = self.worlds     # worlds that stepSimulation steps (see pause)

    # -- reset: terrain, robot and design of each lane -----------------------------------------------------
    def reset(self, seed: int | None = None, options: dict | None = None):
        """Reset all lanes. options: 'designs' (N,4) or (4,), 'levels' (N,) or int, 'design_sampler'."""
        options = options or {}
        if seed is not None:
            self.rngs = [np.random.default_rng([int(seed), int(k)]) for k in self.lane_ids]
        if "design_sampler" in options:
            self.design_sampler = options["design_sampler"]
        if options.get("designs") is not None:
            d = check_design(options["designs"], what="options['designs']")
            self.designs = np.broadcast_to(d, (self.num_envs, 4)).copy()
        if options.get("levels") is not None:
            lv = np.broadcast_to(np.asarray(options["levels"], dtype=np.int64), (self.num_envs,)).copy()
            if lv.min() < 0 or lv.max() > MAX_LEVEL:
                raise ValueError(f"levels must lie in [0, {MAX_LEVEL}], got {lv.min()}..{lv.max()}")
            self.levels = lv
        self._held[:] = 0                  # a full reset draws every lane's design anew
        for i in range(self.num_envs):
            self._reset_lane(i)
            if self.cfg.random_first_episode:   # this episode is cut short at a random point (see BalluConfig)
                self.t[i] = self.rngs[i].integers(self.cfg.episode_steps)
        self._ready, self._stepping = True, self.worlds
        return self.observe(), {"levels": self.levels.copy(), "designs": self.designs.copy()}

    def _reset_lane(self, i):
        if self.design_sampler is not None and self._held[i] % self.cfg.design_hold == 0:
            d = np.asarray(self.design_sampler(self.rngs[i], 1), dtype=float).reshape(4)
            self.designs[i] = check_design(d, what="design_sampler output")[0]
        self._held[i] += 1
        self._set_terrain(i, int(self.levels[i]))
        self._load_robot(i, self.designs[i])
        self.t[i] = 0
        self.ep_return[i] = 0.0
        self.tg_phase[i] = 0.0
        self._ep_actions[i] = []

    def set_design_sampler(self, sampler):
        self.design_sampler = sampler

    def _set_terrain(self, i, level):
        if self._terrain_level[i] != level:
            self.terrain[i] = self._world[i].place_terrain(self.terrain[i], level, self._lane_bit(i))
            self._terrain_level[i] = level

    def _load_robot(self, i, design):
        """(Re)load lane i's robot when its design changed, else reset its pose; the servo starts where the knee
        is, so the first step has no jerk. [ours]"""
        world = self._world[i]
        if self._body_design[i] is None or not np.array_equal(self._body_design[i], design):
            path = os.path.join(self._tmp.name, f"lane{i}.urdf")
            with open(path, "w") as f:
                f.write(robot_urdf(design, self.cfg))
            self.bodies[i] = world.load_robot(self.bodies[i], path, self._lane_bit(i))
            self._body_design[i] = design.copy()
        self._mass[i] = mass_properties(design, self.cfg)["total"]
        self._gcr[i], self._spcf[i] = float(design[2]), float(design[3])
        self._toe_len[i] = design[1] + self.cfg.foot_offset + self.cfg.foot_radius
        world.reset_robot(self.bodies[i])
        m0 = math.radians(self.cfg.start_knee_deg) * 180.0 / 100.0
        self._servo[i], self._servo_goal[i] = [m0, m0], [m0, m0]
        self.last_action[i] = m0 / math.pi

    # -- step: commands, rewards, episode ends and the curriculum ------------------------------------------
    def step(self, actions):
        if not self._ready:
            raise RuntimeError("call reset() before step()")
        a = check_actions(actions, self.num_envs, self.act_dim)
        for i, row in enumerate(a.tolist()):
            self._ep_actions[i].append(row)
        self._command(a, np.arange(self.num_envs))
        for _ in range(self.cfg.decimation):
            self._physics_step()
        self.t += 1
        state = self.read_lanes()
        pos, vel = state.pos, state.vel
        cfg, task = self.cfg, self.cfg.task
        warm = self._warmup()
        rew = reward(task, cfg, state, self.levels, self.designs[:, 1], 1.0 if warm is None else warm[1])
        finite = np.isfinite(pos).all(1) & np.isfinite(vel).all(1) & np.isfinite(rew)
        blowup = ~finite | (np.linalg.norm(np.nan_to_num(vel[:, :3], nan=1e9), axis=1) > cfg.max_speed) \
            | (np.nan_to_num(pos[:, 2], nan=1e9) > cfg.max_z)
        rew = np.where(finite, rew, 0.0)
        self.ep_return += rew
        terminated = blowup
        truncated = (self.t >= cfg.episode_steps) & ~terminated
        obs = self.observe(state)
        done = terminated | truncated
        # info always holds every key (rows of unfinished lanes masked by "_final_obs"): workers' infos concatenate
        info = {"final_obs": np.where(done[:, None], obs, 0.0).astype(np.float32), "_final_obs": done,
                "final_x": np.where(done, pos[:, 0], np.nan),
                "episode_return": np.where(done, self.ep_return, np.nan),
                "episode_level": self.levels.copy(), "blowup": blowup}
        if done.any():
            if self.curriculum and (warm is None or not warm[0]):   # a blown-up episode does not move the level
                moved = curriculum_update(task, self.levels, np.nan_to_num(pos[:, 0]), self.level_step, cfg.strict)
                self.levels = np.where(truncated, moved, self.levels)
            for i in np.flatnonzero(done):
                if blowup[i]:
                    self._body_design[i] = None   # reload a blown-up robot from scratch
                self._reset_lane(i)
            fresh = self.observe()
            obs[done] = fresh[done]
        info["levels"] = self.levels.copy()      # the level each lane plays next
        return obs, rew.astype(np.float32), terminated, truncated, info

    def _command(self, a, lanes):
        """Actions `a` of `lanes` (an index array) -> their servo goals and last actions, through the trajectory
        generator and the action filter if set."""
        if self.cfg.tg:
            a, self.tg_phase[lanes] = tg_command(a, self.tg_phase[lanes], self.cfg)
        if self.cfg.action_smoothing:   # the filtered command (see BalluConfig.action_smoothing)
            b = self.cfg.action_smoothing
            a = b * self.last_action[lanes] + (1.0 - b) * np.clip(a, 0.0, 1.0)
        for i, goal in zip(lanes, servo_target(a).tolist()):
            self._servo_goal[i] = goal
        self.last_action[lanes] = a

    def schedule(self, train_steps: int):
        """The trainer's control steps so far (ppo.train tells it before each rollout): the warm-up
        (cfg.warmup_steps) follows them. An env never told, as in `score`, has no warm-up."""
        self.train_steps = int(train_steps)

    def _warmup(self):
        """While the warm-up runs: (hold the curriculum?, the scale of r_nav); None after it, or without one."""
        W = self.cfg.warmup_steps
        if not W or self.train_steps is None or self.train_steps >= 2 * W:
            return None
        return self.train_steps < W, min(1.0, max(0.0, (self.train_steps - W) / W))

    # -- observe: what the robots' state is and what a policy sees -----------------------------------------
    def read_lanes(self) -> LaneState:
        """Every lane's state (LaneState) for observation, reward, limits and figures: four PyBullet calls per
        robot, gathered in Python lists and turned into arrays once."""
        base, vel, joints, legs = (pybullet.getBasePositionAndOrientation, pybullet.getBaseVelocity,
                                   pybullet.getJointStates, pybullet.getLinkStates)
        rows = []
        for i, b in enumerate(self.bodies):
            cid = self._world[i].cid
            js = joints(b, JOINTS, physicsClientId=cid)
            ll, lr = legs(b, TIBIAE, physicsClientId=cid)
            rows.append((*base(b, physicsClientId=cid), *vel(b, physicsClientId=cid), [s[0] for s in js],
                         [s[1] for s in js], (ll[4], lr[4]), (ll[5], lr[5])))
        pos, orn, lin, ang, jq, jqd, knee, leg_orn = (np.array(c, dtype=float) for c in zip(*rows))
        vel = np.concatenate([lin, ang], axis=1)
        # foot tip = tibia frame origin (the knee) + R (0, 0, -L): the third column of R times -L
        axis = z_axis(leg_orn)
        toe = knee - self._toe_len[:, None, None] * axis
        return LaneState(pos, vel, jq, jqd, toe, orn, knee, axis)

    def observe(self, s: LaneState | None = None):
        """The observation, its blocks in the order of cfg.obs (OBS_FORMS): [paper] base velocities in the base
        frame (as Isaac Lab reports them), joint positions and velocities, last action, then the task cue and
        the normalised design [facts]; or the authors' code's terms [facts]."""
        s = self.read_lanes() if s is None else s
        x0 = task_geometry(self.cfg.task)["x0"]
        blocks = {"base_vel": lambda: [to_base_frame(s.orn, s.vel[:, :3]), to_base_frame(s.orn, s.vel[:, 3:])],
                  "base_lin_vel": lambda: [to_base_frame(s.orn, s.vel[:, :3])],
                  "joint_pos": lambda: [s.jq], "joint_vel": lambda: [s.jqd], "last_action": lambda: [self.last_action],
                  "tg": lambda: [np.sin(2 * np.pi * self.tg_phase)[:, None],
                                 np.cos(2 * np.pi * self.tg_phase)[:, None]],
                  "cue": lambda: [np.stack([x0 - s.pos[:, 0], level_height(self.cfg.task, self.levels)], axis=1)],
                  "pelvis_pos": lambda: [s.pos], "knee_to_edge": lambda: [x0 - s.knee[:, :, 0]],
                  "design": lambda: [normalise_design(self.designs)]}
        return np.concatenate([a for b in obs_blocks(self.cfg) for a in blocks[b]()], axis=1).astype(np.float32)

    # -- physics: the hot loop -----------------------------------------------------------------------------
    def _physics_step(self):
        """One 200 Hz step: per robot, read joints and balloon, apply joint torques and balloon forces; step.
        Knee target: the servo angle x 100/180 [facts] (slewed if `servo_slew`: off, the slew is unbounded);
        hips and neck get their passive damping; each world takes `substeps_fine` substeps if some joint is fast
        or near a limit, else `substeps`. The options off by default run beside this path (`_options`).
        Two PyBullet calls per robot to read and two to write, on the module with the client id (BulletClient's
        wrapper costs more than the calls), and plain-float arithmetic (numpy dispatch costs more at these sizes)."""
        cfg = self.cfg
        per_robot, per_step = self._options()   # both empty by default
        get_joints, get_link, apply, control = (pybullet.getJointStates, pybullet.getLinkState,
                                                pybullet.applyExternalForce, pybullet.setJointMotorControlArray)
        world_frame, torque_mode = pybullet.WORLD_FRAME, pybullet.TORQUE_CONTROL
        slew = cfg.servo_speed * cfg.dt if cfg.servo_slew else math.inf
        ratio, c = 100.0 / 180.0, cfg.passive_damping
        adaptive = cfg.substeps_fine != cfg.substeps
        for world in self._stepping:
            cid, fine = world.cid, False
            for i in world.lanes:
                b = self.bodies[i]
                js = get_joints(b, JOINTS, physicsClientId=cid)
                ls = get_link(b, BALLOON, 1, physicsClientId=cid)
                servo, goal = self._servo[i], self._servo_goal[i]
                servo[0] += min(slew, max(-slew, goal[0] - servo[0]))
                servo[1] += min(slew, max(-slew, goal[1] - servo[1]))
                k = self._spcf[i]
                tau = [-c * js[0][1], -c * js[1][1], -c * js[2][1],
                       knee_torque(js[3][0], js[3][1], servo[0] * ratio, k, cfg),
                       knee_torque(js[4][0], js[4][1], servo[1] * ratio, k, cfg)]
                force = balloon_force(self._gcr[i], self._mass[i], ls[6], cfg)
                apply(b, BALLOON, force, ls[0], world_frame, physicsClientId=cid)
                control(b, JOINTS, torque_mode, forces=tau, physicsClientId=cid)
                for option in per_robot:
                    option(i, b, cid, ls, tau, force)
                if adaptive and not fine:
                    fine = needs_fine_substeps(js, cfg.dt, cfg.fine_speed)
            if adaptive:
                n = cfg.substeps_fine if fine else cfg.substeps
                if n != world.substeps:
                    pybullet.setPhysicsEngineParameter(numSubSteps=bullet_substeps(n), physicsClientId=cid)
                    world.substeps = n
                self.fine_steps += fine
            t0 = time.perf_counter()
            pybullet.stepSimulation(physicsClientId=cid)
            self.sim_seconds += time.perf_counter() - t0   # for the benchmark's physics-only reference
            self.world_steps += 1
        for option in per_step:
            option(self)

    def _options(self) -> tuple:
        """The physics step's options off by default, chosen once per step: (per robot after its torques and
        force are applied, per step after the worlds stepped). The authors' uprighting torque on the balloon
        (`quirk_buoyancy_torque`, a QUIRK [facts]); the monitor (an audit), which reads each robot's applied knee
        torques and balloon force."""
        per_robot = (self._apply_quirk_torque,) if self.cfg.quirk_buoyancy_torque else ()
        if self.monitor is None:
            return per_robot, ()
        return per_robot + (self._record_applied,), (self.monitor,)

    def _apply_quirk_torque(self, i, b, cid, ls, tau, force):
        pybullet.applyExternalTorque(b, BALLOON, quirk_torque(ls[1], force, self.cfg), pybullet.WORLD_FRAME,
                                     physicsClientId=cid)

    def _record_applied(self, i, b, cid, ls, tau, force):
        self._applied[i] = (tau, force)

    # -- worlds --------------------------------------------------------------------------------------------
    def pause(self, lanes):
        """Stop stepping the worlds whose every lane is paused (score's lanes whose result is known: their outputs
        are to be ignored). Other worlds are PyBullet clients of their own: their trajectories do not change."""
        paused = set(int(i) for i in lanes)
        self._stepping = [w for w in self.worlds if not set(w.lanes) <= paused]

    def client(self, i):
        """The PyBullet client (BulletClient) of lane i's world, for tools that inspect a robot."""
        return self._world[i].p

    def _lane_bit(self, i):
        return 1 << (1 + i % self.cfg.lanes_per_world)

    def close(self):
        for world in getattr(self, "worlds", []):
            world.p.disconnect()
        if getattr(self, "worlds", None):
            self.worlds = []
            self._tmp.cleanup()


# ----------------------------------------------------------------------------------------------------------
# 7. VecBallu: W worker processes behind the BalluEnv interface (runkit.lanes runs them)
# ----------------------------------------------------------------------------------------------------------
class VecBallu(VecEnv):
    """`num_envs` lanes split over `workers` processes, each holding a BalluEnv of its lanes (runkit.lanes.VecEnv),
    behind BalluEnv's interface; lane ids are global, so a lane's trajectory does not depend on the worker count."""
    lane_options = {"designs": 1, "levels": 0}   # reset options given per lane: (N, 4) designs, (N,) levels
    mirror = ("obs_dim", "act_dim", "obs_names")
    worker_name = "BALLU worker"

    def __init__(self, num_envs: int, workers: int = 2, cfg: BalluConfig = BalluConfig(),
                 curriculum: bool = True, design_sampler=None, timeout: float = 600.0):
        check_split(num_envs, workers)
        check_config(cfg)
        self.cfg = cfg
        super().__init__(BalluEnv, num_envs, workers, timeout, cfg=cfg, curriculum=curriculum)
        if design_sampler is not None:
            self.set_design_sampler(design_sampler)

    def set_design_sampler(self, sampler):
        self.each_set("design_sampler", sampler)

    def schedule(self, train_steps: int):
        self.each_call("schedule", train_steps)

    levels = property(lambda self: self.gather("levels"))
    designs = property(lambda self: self.gather("designs"))
    sim_seconds = property(lambda self: np.array(self.each_get("sim_seconds")))   # one per worker


def make_env(num_envs: int, workers: int = 1, cfg: BalluConfig = BalluConfig(), **kw):
    """A BalluEnv in this process for one worker, else a VecBallu with `workers` processes."""
    return BalluEnv(num_envs, cfg, **kw) if workers == 1 else VecBallu(num_envs, workers, cfg, **kw)


# ----------------------------------------------------------------------------------------------------------
# 8. The score J(policy, design, task) and scripted controllers
# ----------------------------------------------------------------------------------------------------------
def stand(obs):
    """Scripted floor 1: zero action (servo released, springs hold the knees straight)."""
    return np.zeros((len(obs), ACT_DIM))


stand.pure = True   # row by row, no state: score may reuse its episodes (see score)


class PumpGait:
    """Scripted floor 2: knees pulled fully for half a period, released for the other half; mode="sync" pumps
    both together (a hop), "alternate" half a period apart (a walk). `period` (control steps) and `mode` are a
    scalar or one per lane, so one scoring run can sweep them. The phase is a call counter: all lanes of a
    scoring run start their episodes together."""

    def __init__(self, period=10, mode="sync", amplitude: float = 1.0):
        self.period = np.asarray(period, dtype=float)
        if (self.period < 2).any():
            raise ValueError(f"period={period!r} must be >= 2 control steps")
        self.alternate = np.asarray(mode) == "alternate"
        if not np.isin(np.asarray(mode), ["sync", "alternate"]).all():
            raise ValueError(f"mode={mode!r} must be 'sync' or 'alternate'")
        self.amplitude, self.t = amplitude, 0

    def for_lanes(self, ids):
        """The same gait for a subset of the lanes (score hands each worker the part for its lanes)."""
        pick = lambda x: x if np.ndim(x) == 0 else x[ids]   # noqa: E731  a scalar holds for every lane
        part = PumpGait(pick(self.period), pick(np.where(self.alternate, "alternate", "sync")), self.amplitude)
        part.t = self.t
        return part

    def __call__(self, obs):
        on = (self.t % self.period) < self.period / 2
        self.t += 1
        left = np.where(on, self.amplitude, 0.0)
        right = np.where(self.alternate, self.amplitude - left, left)
        return np.broadcast_to(np.stack(np.broadcast_arrays(left, right), -1), (len(obs), ACT_DIM)).copy()


SCORE_EPISODES = 20                                   # [facts] episodes of the score J


def check_level_steps(level_steps, episodes: int | None) -> np.ndarray:
    """score's schedule as an int array (levels each episode moves), from `level_steps` or `episodes` unit steps."""
    if level_steps is None:
        episodes = SCORE_EPISODES if episodes is None else episodes
        if not isinstance(episodes, (int, np.integer)) or isinstance(episodes, bool) or episodes < 1:
            raise ValueError(f"episodes={episodes!r} must be an integer >= 1")
        return np.ones(episodes, dtype=np.int64)
    steps = list(level_steps) if isinstance(level_steps, (list, tuple, np.ndarray)) else None
    if not steps or not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and 1 <= v <= MAX_LEVEL
                            for v in steps):
        raise ValueError(f"level_steps={level_steps!r} must be None or a non-empty sequence of integers in "
                         f"[1, {MAX_LEVEL}] (levels each episode moves up or down)")
    if episodes is not None and episodes != len(steps):
        raise ValueError(f"episodes={episodes!r} must be None or len(level_steps)={len(steps)}")
    return np.array(steps, dtype=np.int64)


def score(policy, designs, task: str = "obstacle", episodes: int | None = None, start_level: int | None = None,
          workers: int = 1, cfg: BalluConfig | None = None, progress=None, final_x: bool = False,
          level_steps=None, reuse: bool | None = None, stats: dict | None = None, strict: bool = False):
    """J(policy, design, task) for many designs at once: one lane per design, curriculum from the start level.

    The policy (any picklable callable obs (n, OBS_DIM) -> action (n, 2); deterministic for a learned policy;
    one with per-lane settings offers `for_lanes(ids)`, as PumpGait does) plays `episodes` (default 20)
    episodes per design, each moving the lane's level one up or down; the level after the last one is the
    score, in cm (obstacle) or degrees (ramp). [facts]  `cfg` (default: what the policy observed in training,
    `policy_config`) sets the env. workers > 1 split the designs over a long-lived pool (runkit.lanes.score_lanes).
    Each design gets a PyBullet world of its own [ours]: a lane's trajectory can depend on its world-mates once
    robots touch the box, and J must depend neither on the designs sharing its call nor on the worker count (for
    a policy evaluated row by row, as ppo.PolicyFn is). `final_x`: also each episode's final pelvis x
    (n, episodes) in m (NaN for a blown-up episode); `episode_outcome` reads them as short, stay band or cleared.
    `strict` [ours, obstacle only]: the score's curriculum moves down on every episode that does not clear
    (curriculum_update), whatever rule the policy trained with.

    `level_steps` (e.g. (16, 8, 4, 2, 1, 1, 1)) [ours]: a bisection over levels, episode e moving level_steps[e]
    levels; halving steps near the level where the policy starts failing in ~log2(range) episodes, where the unit
    walk takes one a level: (16, 8, 4, 2, 1, 1, 1) reaches +-33 levels in 7 episodes (unit steps: +-20 in 20).
    For GES's probes; None (default) = unit steps, exactly the facts' J.

    `reuse` [ours, exact] (default: on with unit steps for a policy marked `pure = True`, as ppo.PolicyFn and
    `stand` are): play each level of a design's walk once. A pure policy on this deterministic simulator plays
    an episode from its reset state the same way every time (docs/choices.md), and with unit steps the next
    level depends on the level alone, so a walk back at a level it played is filled in and its world stops
    stepping: J and every final x as playing every episode (test). `stats` (a dict) receives "episodes_played".
    """
    cfg = replace(policy_config(policy, task, cfg), lanes_per_world=1,   # one world per design (above)
                  random_first_episode=False, strict=strict)            # J plays whole episodes
    d = check_design(designs, what="designs")
    start = SCORE_START_LEVEL[task] if start_level is None else start_level
    steps = check_level_steps(level_steps, episodes)
    unit = bool((steps == 1).all())
    if not 0 <= start <= MAX_LEVEL:
        raise ValueError(f"start_level={start!r} must lie in [0, {MAX_LEVEL}]")
    if reuse is None:
        reuse = unit and bool(getattr(policy, "pure", False))
    elif reuse and not unit:
        raise ValueError(f"reuse=True needs unit level steps (the walk's next level from the level alone), "
                         f"got level_steps={level_steps!r}")
    final, x, played = score_lanes(partial(BalluEnv, cfg=cfg, curriculum=True), policy, d, workers, start, steps,
                                   reuse, progress, f"score {task}")
    j = level_score(task, final)
    if stats is not None:
        stats["episodes_played"] = played
    return (j, x) if final_x else j


# ----------------------------------------------------------------------------------------------------------
# 9. Command line: bench, strip --out PNG, experiments/ballu_bench.py's, in a child process (ballu imports no tool
#    built on it: the bench and the strip's figure import ballu)
# ----------------------------------------------------------------------------------------------------------
if __name__ == "__main__":
    from runkit.args import delegate
    raise SystemExit(delegate("experiments.ballu_bench"))
