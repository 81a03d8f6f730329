"""ballu.py -- a batched PyBullet simulator of BALLU for the GES co-design paper.

Read top to bottom:
  1. the design vector (l_f, l_t, gcr, spcf), Table I, D2/D3 and design samplers -- paper Sec. III-B, Table I
  2. settings (`BalluConfig`)
  3. the robot: mass properties and a URDF generated from a design         -- docs/facts.md "Robot"
  4. the knee law (spring + tendon PD) and the balloon forces              -- facts "Knee", "Buoyancy and drag"
  5. tasks: obstacle and ramp terrain, curriculum, rewards (paper eq. 4)   -- paper Sec. III-C, facts "Tasks"
  6. `BalluEnv`: N robots, one lane each, in PyBullet worlds of a few lanes; batched API
  7. worker processes: `WorkerPool` (long-lived), `VecBallu` (W workers, each a `BalluEnv`, same API)
  8. the score J(policy, design) and two scripted controllers (stand, pump)
  9. command line: --bench (throughput beside the previous robot's), --strip (a pump gait's motion strip)

This module imports no other module of the project: the learner (ppo.py) and the co-design (ges.py) sit on top.
The physics audit and the open-loop capability search: experiments/ballu_capability.py (docs/capability).

Equation numbers count the paper's numbered equations in order (eq. 4 = the obstacle reward).
Every choice says where it comes from: [paper], [facts] (the authors' code read as facts, see
docs/facts.md), or [ours] where both are silent, with the study in docs/ that measured it. QUIRKs of the
authors' code exist as options, off by default.

The batched interface follows Gymnasium's vector-env conventions without importing gymnasium:
reset(seed=..., options=...) -> (obs, info); step(actions) -> (obs, reward, terminated, truncated, info),
arrays shaped (num_envs, ...); an episode that ends is reset in the same step and its last observation is
in info["final_obs"] (rows flagged by info["_final_obs"]).
"""
from __future__ import annotations

import argparse
import atexit
import contextlib
import copy
import math
import multiprocessing as mp
import os
import tempfile
import time
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np


@contextlib.contextmanager
def quiet_stdout(fds=(1,)):
    """Silence C-level output (file descriptors; 1 = stdout) in a with-block: PyBullet's C code prints
    "argv[0]=" on stdout at every connect, and a build-time banner on stderr (2) at import. C's own buffers
    are flushed before the descriptors come back. Python exceptions still propagate."""
    import ctypes
    import sys
    sys.stdout.flush()
    sys.stderr.flush()
    saved, devnull = [os.dup(fd) for fd in fds], os.open(os.devnull, os.O_WRONLY)
    for fd in fds:
        os.dup2(devnull, fd)
    os.close(devnull)
    try:
        yield
    finally:
        ctypes.CDLL(None).fflush(None)
        for fd, keep in zip(fds, saved):
            os.dup2(keep, fd)
            os.close(keep)


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
# Narrower per-task ranges of the authors' code [facts]; "l" is the symmetric leg length of D3.
TASK_RANGES = {
    "obstacle": {"gcr": (0.75, 0.89), "spcf": (0.001, 0.010), "l": (0.20, 0.48)},
    "ramp": {"gcr": (0.725, 0.89), "spcf": (0.005, 0.100), "l": (0.20, 0.48)},
}
SPACE_NAMES = DESIGN_NAMES + ("l",)
# Physical validity (what the simulator can represent at all), wider than any design space. [ours]
VALID_LOW = np.array([0.05, 0.05, 0.0, 0.0])
VALID_HIGH = np.array([1.00, 1.00, 0.99, 1.0])


@dataclass
class DesignSpace:
    """A BALLU design space: a box of free parameters (names, lows, highs) plus fixed values for the rest of
    (l_f, l_t, gcr, spcf). The free name "l" means l_f = l_t = l (D3). `full` maps a design of the space to the
    full 4-vector a lane receives. The co-design (ges.py) sees only the box: names, lows, highs."""
    names: tuple
    lows: tuple
    highs: tuple
    fixed: dict = field(default_factory=dict)
    task: str | None = None

    def __post_init__(self):
        self.names = tuple(self.names)
        self.lows, self.highs = tuple(map(float, self.lows)), tuple(map(float, self.highs))
        self.fixed = {str(n): float(v) for n, v in self.fixed.items()}
        if not (len(self.names) == len(self.lows) == len(self.highs) >= 1):
            raise ValueError(f"names/lows/highs must have the same length >= 1, got {len(self.names)}/"
                             f"{len(self.lows)}/{len(self.highs)}")
        for n, lo, hi in zip(self.names, self.lows, self.highs):
            if n not in SPACE_NAMES:
                raise ValueError(f"design parameter name {n!r} not in {SPACE_NAMES}")
            if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
                raise ValueError(f"bounds of {n} must be finite with low < high, got [{lo}, {hi}]")
        for n in DESIGN_NAMES:  # every full parameter must come from somewhere
            if n not in self.names and n not in self.fixed and not (n in ("l_f", "l_t") and "l" in self.names):
                raise ValueError(f"parameter {n} is neither free nor fixed in this design space")

    @property
    def d(self) -> int:
        return len(self.names)

    @property
    def lo(self) -> np.ndarray:
        return np.array(self.lows)

    @property
    def hi(self) -> np.ndarray:
        return np.array(self.highs)

    def validate(self, theta) -> np.ndarray:
        """theta as an (n, d) array, or a ValueError naming the parameter and its range. (ges.Box.validate does
        the same for GES's box: a small repeat that keeps ges.py free of the robot.)"""
        arr = np.asarray(theta, dtype=float)
        arr = arr[None, :] if arr.ndim == 1 else arr
        if arr.ndim != 2 or arr.shape[1] != self.d:
            raise ValueError(f"theta has shape {np.shape(theta)}, expected (d,) or (n, d) with d={self.d} "
                             f"columns {self.names}")
        lo, hi = self.lo, self.hi
        tol = 1e-9 * (hi - lo)  # round-off of a unit-cube round trip must not be an error
        for j, n in enumerate(self.names):
            bad = ~np.isfinite(arr[:, j]) | (arr[:, j] < lo[j] - tol[j]) | (arr[:, j] > hi[j] + tol[j])
            if bad.any():
                i = int(np.argmax(bad))
                raise ValueError(f"{n}={float(arr[i, j])!r} (row {i}) is outside the design space: allowed range "
                                 f"[{self.lows[j]}, {self.highs[j]}]")
        return arr

    def sample_uniform(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """n uniform designs of the space (its own coordinates)."""
        return self.lo + rng.random((n, self.d)) * (self.hi - self.lo)

    def to_dict(self) -> dict:
        return {"names": list(self.names), "lows": list(self.lows), "highs": list(self.highs),
                "fixed": dict(self.fixed), "task": self.task}

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


def _bounds(names, task, ranges):
    if task not in (None, "obstacle", "ramp"):
        raise ValueError(f"task={task!r} not allowed: use None, 'obstacle' or 'ramp'")
    if ranges not in ("table", "facts"):
        raise ValueError(f"ranges={ranges!r} not allowed: use 'table' (paper Table I) or 'facts' (per-task)")
    if ranges == "facts" and task is None:
        raise ValueError("ranges='facts' needs task='obstacle' or 'ramp' (the facts' ranges are per task)")
    src = TASK_RANGES[task] if ranges == "facts" else dict(TABLE_I, l=TABLE_I["l_f"])
    return tuple(src[n][0] for n in names), tuple(src[n][1] for n in names)


def d2(task: str | None = None, ranges: str = "table") -> DesignSpace:
    """D2 = (gcr, spcf) with l_f = l_t = 0.45 m (paper Sec. III-B). ranges='table': Table I bounds [paper];
    ranges='facts': the narrower per-task ranges of the authors' code [facts]."""
    lows, highs = _bounds(("gcr", "spcf"), task, ranges)
    return DesignSpace(("gcr", "spcf"), lows, highs, {"l_f": BASELINE[0], "l_t": BASELINE[1]}, task)


def d3(task: str | None = None, ranges: str = "table") -> DesignSpace:
    """D3 = (gcr, spcf, l) with l_f = l_t = l (paper Sec. III-B). l in Table I's leg range [0.25, 0.55]
    [paper], or [0.20, 0.48] with ranges='facts' [facts]."""
    lows, highs = _bounds(("gcr", "spcf", "l"), task, ranges)
    return DesignSpace(("gcr", "spcf", "l"), lows, highs, {}, task)


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


# Design samplers: sampler(rng, n) -> (n, 4) full designs for the lanes that reset (training). Picklable, so
# worker processes receive them.
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
    """Lanes that start each at a uniform level in 0..the level the score J starts from (ppo.train's
    start_level=(low, high)). [ours]  Why: J only sees levels near its start (28 obstacle, 40 ramp),
    while a curriculum from level 0 climbs at most one level per 20 s episode; failing lanes walk down to what
    the policy can do. The protocol's `spread_start` setting; where it is the default: train_start_levels."""
    return (0, SCORE_START_LEVEL[task] if score_start is None else int(score_start))


SPREAD_START_TASKS = ("ramp",)   # [ours] tasks whose training starts spread (train_start_levels)


def train_start_levels(task: str, score_start: int | None = None):
    """A fresh training run's curriculum start: spread (spread_start_levels) on the ramp, level 0 (the facts'
    curriculum) on the obstacle. [ours; the facts start at 0]  Why: on the ramp the spread start scored higher
    on every seed at 1 M steps (+6.4, +8.0, +6.8 deg), the most a 2-core preset trains; on the obstacle it made
    no difference the seeds could resolve. Measured on the previous robot (docs/ppo_protocol)."""
    return spread_start_levels(task, score_start) if task in SPREAD_START_TASKS else 0


START_LEVEL_NAMES = ("task", "spread", "zero")   # the names ppo.py and run_all.py accept for a start


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


HARDWARE_DRAG = 0.4   # [facts] the balloon drag of the authors' May 2025 branch, as an option: drag_coef=0.4


@dataclass
class BalluConfig:
    """Everything the simulator needs besides a design. Defaults: [paper] where it says, else [facts]."""
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
    # knee law  [facts]
    # Spring preload q0 = 72.35 deg as the authors' robot configuration and morphology loader set it [facts];
    # pi/4 (45 deg) is the previous robot's (PREVIOUS_ROBOT, kept to measure against).
    spring_preload: float = math.radians(72.35)   # tau_spring = -2 k (q + q0) - spring_damping qdot
    spring_damping: float = 0.001
    pd_p: float = 1.0
    pd_d: float = 0.08
    tau_max: float = 0.0848               # N m, servo torque limit
    servo_speed: float = 7.48             # rad/s, 60 deg / 0.14 s: clips the D term's knee velocity [facts]
    # Hardware-like servo [ours, option]: the horn slews at <= servo_speed, so the knee target moves at
    # <= 4.16 rad/s. Off by default: the paper's simulation sets the knee target at once every control step
    # [facts]. With the slew on, open-loop toe clearances fall several-fold (docs/capability), closer to the
    # real robot (24 cm / 8 cm), far from the paper's simulation.
    servo_slew: bool = False
    # Passive hips and neck: joint damping 0.001 N m s/rad as in the authors' robot [facts], applied as an
    # explicit torque -c qdot (URDF joint damping on these tiny inertias blows PyBullet up [facts]).
    passive_damping: float = 0.001
    # balloon  [facts]: no drag in the authors' simulation as they run it now (drag 0 since June 2025).
    # HARDWARE_DRAG (0.4: F_d = -sign(v) 0.4 v^2 per world axis, their May 2025 branch) is the option that caps
    # how high a high-gcr robot flies, closer to the hardware's 24 cm (docs/capability).
    drag_coef: float = 0.0
    # QUIRK: their code adds a torque r x F, r = 0.38 m from the neck along the balloon's axis (rotating with
    # it), so lift acts as if 0.76 m above the neck: an extra uprighting torque when the balloon tilts.
    quirk_buoyancy_torque: bool = False
    gravity: float = 9.81
    # start pose  [facts]
    start_hip_deg: float = 1.0
    start_knee_deg: float = 27.35
    start_z: float = 1.2
    # friction  [facts]: PhysX combines two materials by the mode of higher priority. Their ground uses
    # 'multiply' (0.5 x the robot's default 0.5 = 0.25); the box keeps the default material (0.5); the ramp's
    # material 0.8 meets the robot's 0.5 under the default 'average' (0.65). PyBullet multiplies the two bodies'
    # lateral frictions, so the robot gets 1.0 and each surface the product.
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
    # [facts, an option] the authors' schedule: for the first `warmup_steps` control steps of training (all lanes
    # together; ppo.train tells the env through `schedule`) the curriculum holds every lane's level and r_nav is
    # off, then r_nav ramps in linearly over the next `warmup_steps`. They do it for 100 of 1,500 updates; 0 = off.
    warmup_steps: int = 0
    # [paper / facts] what the policy observes (OBS_FORMS, `obs_names`): "paper" = the paper's text (base
    # velocities, joints, last action) plus the task cue and the design; "code" = the terms the authors'
    # policies observed (their obstacle / ramp environment configurations): pelvis position, the knees' distances
    # to the box edge, no base angular velocity; "code_vel" [facts + ours, the default] = "code" with the paper's
    # base velocities in front: measured best on both tasks (e2e MLP J at 2 M steps, 3 seeds: obstacle 24.3 +- 0.3
    # cm against the paper form's 18.5 +- 1.7, ramp 30.0 +- 1.2 deg against 28.9 +- 1.5; docs/ppo_protocol/README.md,
    # "The authors' MDP").
    obs: str = "code_vel"
    # [ours] per-step reward x control dt, as stock Isaac Lab's reward manager does. The authors' fork divides
    # the sum by dt again (its per-step reward is unscaled): that is reward_dt_scale=False [facts]. Kept
    # because every PPO setting here was tuned at this scale (docs/ppo_protocol screens the reward scale).
    reward_dt_scale: bool = True
    # safety limits [facts]: end an episode on non-finite state, pelvis speed > 10 m/s or z > 5 m
    max_speed: float = 10.0
    max_z: float = 5.0
    # [ours] lanes per PyBullet world (client), all at the same spot. One lane per world: each world picks its
    # own substeps (below), so a lane's trajectory never depends on its world-mates, in training as in `score`.
    # Bullet's broadphase pairs every overlapping bounding box, so stacked lanes cost ~B^2, while each world
    # costs a fixed overhead per step: 16 lanes on one core, 16 x 1 ran within the VM's noise of 4 x 4
    # (`python ballu.py --bench` prints the sweep).
    lanes_per_world: int = 1
    # [ours] episodes a training lane keeps a design drawn by its design sampler before it draws the next. The
    # curriculum level is the lane's: with a new design every episode (1) a lane's level follows the average
    # design, so a design that could clear 38 cm open loop trains at the ~16 cm the average one clears
    # (docs/ppo_protocol). Holding a design lets the level climb to what that design allows; the authors fix each
    # env's design for the whole run [facts]. Screened on the obstacle, 3 seeds: hold 10 and 40 scored no higher at
    # 1 M steps (-0.1 +- 2.0 and -1.2 +- 0.6 cm against 1), so 1 stays. Scoring is unaffected.
    design_hold: int = 1
    # [facts] the authors' training starts each env's first episode at a random step of its 20 s
    # (rsl_rl's init_at_random_ep_len), so the envs' episodes do not all begin and end together: with 32 lanes
    # reset at once, a 64-step rollout would hold the same ~3 s of every episode (only approaches, or only
    # the box). Off by default: screened, -0.3 +- 0.8 cm at 1 M steps, 3 seeds (docs/ppo_protocol); `score`
    # always plays whole episodes.
    random_first_episode: bool = False
    # [ours, an option] a low-pass filter on the servo command: each control step applies
    # beta * (last applied action) + (1 - beta) * (new action clipped to [0, 1]), and the observation's "last
    # action" is the applied one. White policy noise then moves the knees as noise correlated in time (what the
    # robot feels), while PPO's log-probabilities and KL stay those of the Gaussian, so the adaptive rate is
    # not starved as it was with correlated noise in the policy (docs/ppo_protocol). beta = exp(-2 pi f / 20 Hz)
    # for a cut-off f: 0.53 at 2 Hz, 0.21 at 5 Hz. 0 = off (the paper's env).
    action_smoothing: float = 0.0
    # [ours, an option] Policies Modulating Trajectory Generators (Iscen et al. 2018): the policy acts with 4
    # numbers (c_l, c_r, f, A), and knee k gets c_k + 0.5 A sin(2 pi phase) (A clipped to [0, 1]; the result to
    # the servo range): a pump of both knees together, which open-loop search finds clearing 13-62 cm on the
    # protocol's designs (docs/capability), around centres c_k the policy sets. The phase advances by
    # tg_freq[0] + f (tg_freq[1] - tg_freq[0]) (f clipped to [0, 1]) per second; the observation shows its sine
    # and cosine. A policy's mean action 0.5 starts as a 2.75 Hz pump of half amplitude. Off: the paper's two
    # knee commands.
    tg: bool = False
    tg_freq: tuple = (0.5, 5.0)           # Hz for f = 0 .. 1: pump periods of 40 .. 4 control steps
    # [ours] terrain width across the lane. The facts give the obstacle 2 m; with 2 m a PPO policy learned to
    # walk around the ramp (1.7 m sideways, then forward beside it). 10 m makes that impossible in 20 s.
    terrain_width: float = 10.0
    solver_iterations: int = 10           # [ours] PyBullet contact solver iterations (measured stable)
    # Stability with the instant knee target [ours], measured by
    # `python -m experiments.ballu_capability --audit 200` (random open-loop bang-bang actions on random D3
    # designs; docs/capability): with the facts' bare robot 45 % of episodes blew up.
    # - pelvis_inertia: the pelvis is a 2 g rod spinning freely about the hip axis (passive neck and hips),
    #   pitch inertia 2.9e-8 kg m^2; it whirled at PyBullet's 100 rad/s joint-speed cap and exploded. A floor
    #   of 1e-4 on its three axes (a free axle; the legs' inertia about the hips is 8e-5..5e-4 each) ends that.
    #   The limbs keep their true inertia.
    # - substeps: Bullet activates a joint-limit constraint only once the joint is already past the limit,
    #   so a knee slammed at 10-30 rad/s overshoots by v dt (up to 0.17 rad at 200 Hz). PyBullet substeps
    #   (knee torques and balloon forces held over the 5 ms step) shrink dt. Adaptive: `substeps` (4) in a
    #   physics step where every joint is slow and clear of its limits, `substeps_fine` (8) where some joint
    #   moves faster than `fine_speed` or would cross a limit within the step. It passes the audit as fixed 8
    #   substeps do, at ~1.7x their env rate; plain 4 overshoots (docs/capability). fine_speed 10 rad/s: its
    #   200-episode energy rises match fixed 8's (99th percentile 3.35 against 3.37 mJ; 15 rad/s: 4.05) at the
    #   same speed within the machine's noise. substeps_fine = substeps gives a fixed count. Tried without effect
    #   on the overshoot: erp 0-0.9, 50 solver iterations, the PGS and Dantzig MLCP solvers.
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


# The robot before the simulator matched the authors' current one: balloon drag, 45 deg spring preload, each
# surface's friction as its material alone (robot 1.0), no passive damping, fixed 8 substeps in worlds of 4 lanes.
# Kept to measure against (the bench, docs/capability), not as an option to train with.
PREVIOUS_ROBOT = dict(drag_coef=HARDWARE_DRAG, spring_preload=math.pi / 4, friction_ground=0.5,
                      friction_ramp=0.8, passive_damping=0.0, substeps=8, substeps_fine=8, lanes_per_world=4)
# ----------------------------------------------------------------------------------------------------------
# 3. The robot: mass properties and URDF
# ----------------------------------------------------------------------------------------------------------
# Link order in the URDF (PyBullet link index = joint index): the root is the pelvis (-1).
NECK, HIP_L, KNEE_L, HIP_R, KNEE_R = 0, 1, 2, 3, 4
BALLOON, FEMUR_L, TIBIA_L, FEMUR_R, TIBIA_R = 0, 1, 2, 3, 4
KNEES = [KNEE_L, KNEE_R]
JOINTS = [NECK, HIP_L, HIP_R, KNEE_L, KNEE_R]    # observation order
JOINT_LIMITS = np.array([[-math.pi / 2, math.pi / 2]] * 3 + [[0.0, math.radians(100)]] * 2)   # JOINTS order [facts]
TIBIAE = [TIBIA_L, TIBIA_R]


def _cyl(m, r, h):
    """Inertia diagonal of a solid cylinder along z."""
    return np.array([m * (3 * r * r + h * h) / 12, m * (3 * r * r + h * h) / 12, m * r * r / 2])


def mass_properties(design, cfg: BalluConfig = BalluConfig()) -> dict:
    """Mass, centre of mass (z in the link frame) and inertia diagonal of each link: mass = volume x density.

    The tibia link carries the tibia cylinder, the electronics cylinder at its end and the foot sphere
    (one rigid body, so no fixed joints cost solver time). [facts]
    """
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
    """URDF text for one design: pelvis root; passive neck and hips; spring/tendon knees (torque driven).

    No URDF joint damping: on these tiny inertias it makes PyBullet explode. [facts]
    """
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
    tau = clip(tau_spring + tau_pd, -0.0848, 0.0848).  The D term sees the knee velocity clipped to the
    servo's speed [facts]. Plain floats: it runs per knee per physics step.
    """
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
    """QUIRK of the authors' code: torque r x F, r = 0.38 m along the balloon's own axis (rotating with it).

    Added to the force at the balloon's centre, lift acts as if 0.76 m above the neck: when the balloon tilts,
    r x lift turns it back upright. Off by default (`quirk_buoyancy_torque`). [facts, QUIRK]
    """
    x, y, z, w = balloon_orn
    r = cfg.balloon_above_neck
    rx, ry, rz = r * 2 * (x * z + w * y), r * 2 * (y * z - w * x), r * (1 - 2 * (x * x + y * y))  # R (0, 0, r)
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


def curriculum_update(task: str, level, final_x, step=1):
    """Up one level past `up`, down one short of `down`, clipped to 0..74. [facts]  `step` (a scalar or one per
    lane) moves that many levels instead: score's bisection schedule (`level_steps`) uses it. [ours]"""
    g = task_geometry(task)
    move = (np.asarray(final_x) > g["up"]).astype(np.int64) - (np.asarray(final_x) < g["down"])
    return np.clip(np.asarray(level) + np.asarray(step) * move, 0, MAX_LEVEL)


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
    is each lane's tibia length.
    """
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
    """The trajectory generator (cfg.tg) [ours]: actions (c_l, c_r, f, A) and the phases (cycles) of their
    lanes -> the two knee commands and the advanced phases."""
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


def to_base_frame(quat, v):
    """World vectors v (n, 3) expressed in the frames of the unit quaternions quat (n, 4) = (x, y, z, w): R^T v."""
    q, w = quat[:, :3], quat[:, 3:]
    t = 2.0 * np.cross(q, v)            # R^T v = v - w t + q x t for the conjugate rotation
    return v - w * t + np.cross(q, t)


# ----------------------------------------------------------------------------------------------------------
# 6. BalluEnv: N robots, one lane each, in worlds of a few lanes
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
    """The BalluConfig a policy plays `task` on: `cfg` if given, else the observation it trained with (a learned
    policy keeps its entries' names: ppo.PolicyFn.obs_names; one from a checkpoint older than the names observed
    the paper's form), else the default. A policy that observed other entries than cfg gives is a clear error:
    by name, or by count for a checkpoint without names."""
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
TG_OBS_NAMES = list(obs_names(BalluConfig(tg=True)))             # with BalluConfig.tg: its phase after a_l, a_r
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
    `speed` rad/s or would cross a limit within dt at its present speed. Bullet activates a limit only once the
    joint is past it, so such a step needs short substeps to keep the overshoot small (BalluConfig.substeps)."""
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
        """A robot loaded from `urdf_path` in place of `body` (-1: none yet): the robot's friction, no PyBullet
        damping [facts: see passive_damping], collisions with the ground and bit `bit`, velocity motors off
        (force 0) so torque control acts alone. Returns its body id."""
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
        actions so far. [ours] Not PyBullet's own state: saveState/restoreState does not restore contacts
        exactly (restored onto the very world it was saved from, a run diverged within 1-2 control steps at 2 of
        3 save points, docs/ppo_protocol "Resumed runs"). An episode depends on nothing before its start (the
        robot is dropped from start_z, so no contact survives a reset), so set_state replays the episode (test:
        bit for bit). None where lanes share worlds (lanes_per_world > 1: a world-mate's replay would move them)."""
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
    """N BALLU robots, one lane each, stepped together in PyBullet worlds (DIRECT mode, no GUI).

    Lanes are grouped into worlds of `cfg.lanes_per_world`. Within a world all lanes lie on top of each other
    at y = 0, each with its own terrain body and its own collision-filter bit, so a robot touches only the
    ground plane and its own terrain. Every lane sits at the same coordinates because this chaotic system turns
    floating-point rounding into different trajectories (a lane offset sideways rounds its contacts
    differently). Without contacts a lane's trajectory is bit-identical in any world, alone or with any
    neighbours; once robots touch their boxes it can depend on the world-mates (see lanes_per_world). Each lane
    has its own design, curriculum level and random generator (seeded from (seed, lane id)).

    Designs of reset lanes come from `design_sampler(rng, n) -> (n, 4)` if one is set (training: a new draw
    every `cfg.design_hold` episodes, and at every full reset), else a lane keeps its design (scoring). With
    `curriculum=True` each finished episode moves the lane's level. Read as reset, step, observe, physics; the
    saved state that resumes a killed training exactly (get_state, set_state) is _ExactResume's.
    """

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
        # info always holds every key (rows of unfinished lanes masked by "_final_obs"), so worker
        # processes' infos concatenate without special cases.
        info = {"final_obs": np.where(done[:, None], obs, 0.0).astype(np.float32), "_final_obs": done,
                "final_x": np.where(done, pos[:, 0], np.nan),
                "episode_return": np.where(done, self.ep_return, np.nan),
                "episode_level": self.levels.copy(), "blowup": blowup}
        if done.any():
            if self.curriculum and (warm is None or not warm[0]):   # a blown-up episode does not move the level
                moved = curriculum_update(task, self.levels, np.nan_to_num(pos[:, 0]), self.level_step)
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
        x, y, z, w = np.moveaxis(leg_orn, -1, 0)
        axis = np.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], axis=-1)
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

        Knee target: the servo angle x 100/180, set at once from the last action [facts], or moved at <= the
        servo speed if `servo_slew` (hardware-like option). Hips and neck get their passive damping. Each world
        (one lane by default) steps with `substeps_fine` substeps if some joint is fast or near a limit, else
        `substeps` (see BalluConfig). Two PyBullet calls per robot to read and two to write, on the module with
        the client id (the BulletClient wrapper costs more per call than the calls themselves); the per-robot
        arithmetic is on plain floats, which beats numpy dispatch at these sizes.
        """
        cfg = self.cfg
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
                if cfg.quirk_buoyancy_torque:
                    pybullet.applyExternalTorque(b, BALLOON, quirk_torque(ls[1], force, cfg), world_frame,
                                                 physicsClientId=cid)
                if self.monitor is not None:
                    self._applied[i] = (tau, force)
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
        if self.monitor is not None:
            self.monitor(self)

    # -- worlds --------------------------------------------------------------------------------------------
    def pause(self, lanes):
        """Stop stepping the worlds whose every lane is paused (score pauses lanes whose result is known; their
        robots stand still, their outputs are to be ignored). Other worlds are PyBullet clients of their own,
        so their trajectories do not change."""
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
# 7. Worker processes: a pool of long-lived workers, and VecBallu (W workers behind the BalluEnv interface)
# ----------------------------------------------------------------------------------------------------------
def _serve(conn):
    """A worker's loop: run fn(state, *args) for each request; `state` is this worker's private dict, alive as
    long as the worker. Exceptions travel back as ('error', traceback)."""
    import traceback
    os.environ.setdefault("OMP_NUM_THREADS", "1")   # before torch loads: the workers share the cores, one each
    state = {}
    try:
        while True:
            msg = conn.recv()
            if msg is None:
                break
            fn, args = msg
            try:
                conn.send(("ok", fn(state, *args)))
            except Exception:
                conn.send(("error", traceback.format_exc()))
    except (EOFError, KeyboardInterrupt):
        pass
    finally:
        for v in state.values():
            if hasattr(v, "close"):
                v.close()


class WorkerPool:
    """`workers` long-lived spawned processes that run top-level functions fn(state, *args) side by side.

    Start-up (a fresh interpreter importing numpy, PyBullet and often torch) costs seconds, so a pool is made
    once and reused: VecBallu keeps one per env (each worker's `state` holds its BalluEnv), and `score` and
    the open-loop tools share one per worker count (`shared_pool`). A worker that dies raises RuntimeError in
    the caller instead of hanging.
    """

    def __init__(self, workers: int = 2, timeout: float = 600.0):
        if not isinstance(workers, (int, np.integer)) or workers < 1:
            raise ValueError(f"workers={workers!r} must be an integer >= 1")
        ctx = mp.get_context("spawn")   # no fork: the parent may hold torch threads
        self.timeout, self.conns, self.procs = timeout, [], []
        for _ in range(workers):
            a, b = ctx.Pipe()
            proc = ctx.Process(target=_serve, args=(b,), daemon=True)
            proc.start()
            b.close()
            self.conns.append(a)
            self.procs.append(proc)

    @property
    def workers(self) -> int:
        return len(self.procs)

    def _recv(self, k):
        conn, proc = self.conns[k], self.procs[k]
        t0 = time.monotonic()
        while not conn.poll(0.5):
            if not proc.is_alive():
                raise RuntimeError(f"BALLU worker {k} died (exit code {proc.exitcode})")
            if time.monotonic() - t0 > self.timeout:
                raise RuntimeError(f"BALLU worker {k} did not answer within {self.timeout} s")
        try:
            status, out = conn.recv()
        except (EOFError, OSError):
            proc.join(timeout=1)
            raise RuntimeError(f"BALLU worker {k} died (exit code {proc.exitcode})") from None
        if status == "error":
            raise RuntimeError(f"BALLU worker {k} failed:\n{out}")
        return out

    def call(self, fn, args: list) -> list:
        """fn(state_k, *args[k]) in workers k = 0..len(args)-1 at once; their results, in order. `fn` must be a
        top-level function (pickled by name)."""
        if len(args) > len(self.conns):
            raise ValueError(f"call got {len(args)} argument tuples for {len(self.conns)} workers")
        for conn, a in zip(self.conns, args):
            try:
                conn.send((fn, tuple(a)))
            except (BrokenPipeError, OSError):
                pass   # _recv reports the dead worker
        return [self._recv(k) for k in range(len(args))]

    def close(self):
        for conn in self.conns:
            try:
                conn.send(None)
            except (BrokenPipeError, OSError):
                pass
        for proc in self.procs:
            proc.join(timeout=5)
            if proc.is_alive():
                proc.terminate()
        self.conns, self.procs = [], []

    def __del__(self):
        if getattr(self, "procs", None):
            self.close()


class InProcess:
    """A one-worker WorkerPool that is this process: the same fn(state, *args) calls, with the arguments
    copied as a worker would receive them (so a stateful policy, e.g. PumpGait's phase counter, is not advanced
    in the caller's hands: workers=1 and workers=2 give the same result)."""

    def __init__(self):
        self.state, self.workers = {}, 1

    def call(self, fn, args: list) -> list:
        if len(args) > 1:
            raise ValueError(f"call got {len(args)} argument tuples for 1 worker")
        return [fn(self.state, *copy.deepcopy(a)) for a in args]


def plain_call(state, fn, args):
    """Run a plain top-level function fn(*args) in a worker (its state unused)."""
    return fn(*args)


_SHARED_POOLS: dict = {}


def shared_pool(workers: int) -> WorkerPool:
    """The process-wide pool of `workers` workers for scoring and the open-loop tools, started on first use
    and closed at exit; a dead one is replaced."""
    pool = _SHARED_POOLS.get(workers)
    if pool is None or not all(p.is_alive() for p in pool.procs):
        if pool is not None:
            pool.close()
        pool = _SHARED_POOLS[workers] = WorkerPool(workers)
    return pool


def close_shared_pools():
    for pool in _SHARED_POOLS.values():
        pool.close()
    _SHARED_POOLS.clear()


atexit.register(close_shared_pools)


# what a VecBallu worker does with the BalluEnv in its state
def _env_open(state, num_envs, cfg, lane_ids, curriculum):
    state["env"] = BalluEnv(num_envs, cfg, lane_ids=lane_ids, curriculum=curriculum)


def _env_call(state, method, *args, **kw):
    return getattr(state["env"], method)(*args, **kw)


def _env_get(state, name):
    return getattr(state["env"], name)


def _env_set(state, name, value):
    setattr(state["env"], name, value)


def _env_run(state, fn, args):
    return fn(state["env"], *args)


class VecBallu:
    """`num_envs` lanes split over `workers` processes (a WorkerPool whose workers hold one BalluEnv each);
    the same interface as BalluEnv. Lane ids are global, so a lane's random generator and trajectory do not
    depend on the worker count.
    """

    def __init__(self, num_envs: int, workers: int = 2, cfg: BalluConfig = BalluConfig(),
                 curriculum: bool = True, design_sampler=None, timeout: float = 600.0):
        if not isinstance(workers, (int, np.integer)) or workers < 1:
            raise ValueError(f"workers={workers!r} must be an integer >= 1")
        if not isinstance(num_envs, (int, np.integer)) or num_envs < workers:
            raise ValueError(f"num_envs={num_envs!r} must be an integer >= workers={workers}")
        check_config(cfg)
        self.num_envs, self.cfg = int(num_envs), cfg
        self.obs_dim, self.act_dim = dims(cfg)
        self.obs_names = obs_names(cfg)   # kept in a checkpoint: a policy runs only on what it observed
        self.splits = np.array_split(np.arange(num_envs), workers)
        self.pool = WorkerPool(workers, timeout)
        self.pool.call(_env_open, [(len(ids), cfg, ids, curriculum) for ids in self.splits])
        if design_sampler is not None:
            self.set_design_sampler(design_sampler)

    @property
    def procs(self):
        return self.pool.procs

    def _each(self, fn, *args):
        return self.pool.call(fn, [args] * self.pool.workers)

    def _split(self, x):
        return [None if x is None else np.asarray(x)[ids] for ids in self.splits]

    def set_design_sampler(self, sampler):
        self._each(_env_set, "design_sampler", sampler)

    def schedule(self, train_steps: int):
        self._each(_env_call, "schedule", train_steps)

    @property
    def levels(self):
        return np.concatenate(self._each(_env_get, "levels"))

    @property
    def sim_seconds(self):
        return np.array(self._each(_env_get, "sim_seconds"))

    @property
    def designs(self):
        return np.concatenate(self._each(_env_get, "designs"))

    def reset(self, seed=None, options=None):
        options = dict(options or {})
        per = []
        for ids in self.splits:
            o = dict(options)
            for key in ("designs", "levels"):
                if o.get(key) is not None and np.ndim(o[key]) > (1 if key == "designs" else 0):
                    o[key] = np.asarray(o[key])[ids]
            per.append(("reset", seed, o))
        outs = self.pool.call(_env_call, per)
        return np.concatenate([o[0] for o in outs]), _merge([o[1] for o in outs])

    def get_state(self) -> list | None:
        """The workers' BalluEnv.get_state(), lane by lane in order (None where lanes share worlds)."""
        parts = self._each(_env_call, "get_state")
        return None if None in parts else [lane for part in parts for lane in part]

    def set_state(self, lanes: list):
        """BalluEnv.set_state in each worker with its lanes' saved state (any worker count: the state is per
        lane)."""
        if len(lanes) != self.num_envs:
            raise ValueError(f"saved state holds {len(lanes)} lanes, this env {self.num_envs}")
        self.pool.call(_env_call, [("set_state", [lanes[i] for i in ids]) for ids in self.splits])

    def step(self, actions):
        a = check_actions(actions, self.num_envs, self.act_dim)
        outs = self.pool.call(_env_call, [("step", part) for part in self._split(a)])
        return tuple(np.concatenate([o[j] for o in outs]) for j in range(4)) + (_merge([o[4] for o in outs]),)

    @property
    def parts(self) -> list:
        """Lane indices of each worker, in order."""
        return self.splits

    def run(self, fn, args: list) -> list:
        """fn(worker_env, *args[k]) in every worker k at once; their results, in order. `fn` must be a top-level
        function (pickled by name). ppo.train rolls out so: each worker steps its lanes with its own policy copy."""
        if len(args) != self.pool.workers:
            raise ValueError(f"run needs one argument tuple per worker ({self.pool.workers}), got {len(args)}")
        return self.pool.call(_env_run, [(fn, tuple(a)) for a in args])

    def close(self):
        self.pool.close()


def check_actions(actions, n: int, act_dim: int = ACT_DIM) -> np.ndarray:
    """Actions as a float (n, act_dim) array, or a clear error (wrong shape, NaN or inf)."""
    a = np.asarray(actions, dtype=float)
    if a.shape != (n, act_dim):
        raise ValueError(f"actions must have shape ({n}, {act_dim}), got {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError("actions contain non-finite values (NaN or inf)")
    return a


def _merge(infos):
    return {k: np.concatenate([np.asarray(i[k]) for i in infos]) for k in infos[0]}


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
    """Scripted floor 2: knees pulled fully for half a period, released for the other half.

    mode="sync" pumps both knees together (a hop); mode="alternate" pumps them half a period apart (a walk).
    `period` is in control steps (20 Hz), a scalar or one per lane, so one scoring run can sweep periods;
    `mode` may also be one per lane. The phase is a call counter: all lanes of a scoring run start their
    episodes together.
    """

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


def _score_open(state, policy, designs, lane_ids, cfg, start, steps, reuse=False):
    """Scoring, step 1 (in a worker, or in this process with a local `state`): a fresh env, one lane per design;
    `steps[e]` = levels episode e moves (see score's `level_steps`); `reuse`: replay known episodes (score)."""
    n, episodes = len(designs), len(steps)
    env = BalluEnv(n, cfg, lane_ids=lane_ids, curriculum=True)
    obs, _ = env.reset(seed=0, options={"designs": designs, "levels": np.full(n, start)})
    env.level_step = np.full(n, steps[0])   # each lane's current episode's step; moves on as episodes end
    state["score"] = {"env": env, "policy": policy, "obs": obs, "count": np.zeros(n, dtype=int), "steps": steps,
                      "final": np.full(n, -1), "x": np.full((n, episodes), np.nan),
                      "known": [{} for _ in range(n)] if reuse else None, "episodes_played": 0}


def _replay_known(s, lanes, levels):
    """Lanes whose next level was played before: a deterministic policy on a deterministic simulator repeats
    that episode exactly, and with unit steps the walk's next level depends on the level alone, so the rest of
    the walk is a cycle through known episodes. Fill it in (final x of each episode, the final level)."""
    count, x, final, known, episodes = s["count"], s["x"], s["final"], s["known"], len(s["steps"])
    for i, lv in zip(lanes, levels):
        lv = int(lv)
        if lv not in known[i]:
            continue
        while count[i] < episodes:
            lv_next, x[i, count[i]] = known[i][lv]
            count[i], lv = count[i] + 1, lv_next
        final[i] = lv


def _score_play(state, until):
    """Scoring, step 2: play until every lane has finished `until` of its episodes; the level after a lane's
    last episode is its result (-1 until then). Also returns each episode's final pelvis x."""
    s = state["score"]
    env, policy, count, final, x, steps = s["env"], s["policy"], s["count"], s["final"], s["x"], s["steps"]
    episodes, known = len(steps), s["known"]
    while (np.minimum(count, episodes) < until).any():
        if known is None:
            actions = policy(s["obs"])
        else:   # a pure policy acts row by row: only the lanes still playing are asked
            playing = count < episodes
            some = policy(s["obs"][playing])
            actions = np.zeros((len(count), np.shape(some)[1]))
            actions[playing] = some
        s["obs"], _, _, _, info = env.step(actions)
        done = info["_final_obs"] & (count < episodes)
        if done.any():
            ids = np.flatnonzero(done)
            x[ids, count[ids]] = info["final_x"][ids]
            s["episodes_played"] += len(ids)
            if known is not None:   # a blown-up episode is not kept: its level is played again
                for i in ids[~info["blowup"][ids]]:
                    known[i][int(info["episode_level"][i])] = (int(info["levels"][i]), float(info["final_x"][i]))
            count += done
            env.level_step = steps[np.minimum(count, episodes - 1)]   # the next episode's step
            hit = done & (count == episodes)
            final[hit] = info["levels"][hit]
            if known is not None:
                more = ids[count[ids] < episodes]
                _replay_known(s, more, info["levels"][more])
            env.pause(np.flatnonzero(count >= episodes))   # finished lanes: their worlds stop stepping
    return final.copy(), x.copy(), s["episodes_played"]


def _score_close(state):
    s = state.pop("score", None)
    if s is not None:
        s["env"].close()


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
          level_steps=None, reuse: bool | None = None, stats: dict | None = None):
    """J(policy, design, task) for many designs at once: one lane per design, curriculum from the start level.

    The policy (any picklable callable obs (n, OBS_DIM) -> action (n, 2); deterministic for a learned policy;
    one with per-lane settings offers `for_lanes(ids)`, as PumpGait does) plays `episodes` (default 20)
    episodes per design, each moving the lane's level one up or down; the level after the last one is the
    score, in cm (obstacle) or degrees (ramp). [facts]  `cfg` (default: what the policy observed in training,
    `policy_config`) sets the env; a policy never plays on entries it did not observe. With workers > 1 the
    designs are split over the long-lived `shared_pool`, each worker playing its lanes with its own copy of the
    policy (no round trip per step, no process start-up per call). Each design gets a PyBullet world of its own
    (lanes_per_world = 1)
    [ours]: a lane's trajectory can depend on which lanes share its world once robots touch the box, and a
    design's J must not depend on which designs share its call or on the worker count (for a learned policy
    evaluated row by row, as ppo.PolicyFn is). With `final_x`, also each episode's final pelvis x
    (n, episodes) in m (NaN for a blown-up episode).

    `level_steps` (e.g. (16, 8, 4, 2, 1, 1, 1)): a bisection over levels instead, episode e moving
    level_steps[e] levels up or down; episodes = len(level_steps). [ours]  Why: the unit walk ends near the
    level where the policy starts failing, reached one level per 20 s episode; halving steps reach it in
    ~log2(range) episodes, then a few unit steps settle it as the unit walk does. (16, 8, 4, 2, 1, 1, 1)
    reaches +-33 levels (the unit walk: +-20) in 7 episodes, ~3x cheaper. Meant for GES's probes; the paper's
    J (tables, test designs) keeps the unit steps. None (default) = unit steps, exactly the facts' J.

    `reuse` (default: on for a policy marked `pure = True`, as ppo.PolicyFn and `stand` are, with unit steps):
    play each level of a design's walk once. [ours, exact]  An episode starts from the same reset
    state, and a pure policy (no state, each row's action from that row alone) on this deterministic simulator
    plays it the same way every time: measured, 83 of 83 revisited levels ended at a bit-identical pelvis x
    (an e2e MLP, 8 designs). With unit steps the next level depends on the level alone, so once a walk
    reaches a level it played before, the rest of it cycles through known episodes: it is filled in, and the
    design's world stops stepping. The J and every episode's final x are those of playing all 20 (test).
    A walk that holds its level or swings between two costs 1-2 episodes after it gets there.
    `stats` (a dict) receives "episodes_played", the episodes actually simulated (what a J costs).
    """
    cfg = replace(policy_config(policy, task, cfg), lanes_per_world=1,   # one world per design (above)
                  random_first_episode=False)                            # J plays whole episodes
    d = check_design(designs, what="designs")
    start = SCORE_START_LEVEL[task] if start_level is None else start_level
    steps = check_level_steps(level_steps, episodes)
    episodes, unit = len(steps), bool((steps == 1).all())
    if not 0 <= start <= MAX_LEVEL:
        raise ValueError(f"start_level={start!r} must lie in [0, {MAX_LEVEL}]")
    if reuse is None:
        reuse = unit and bool(getattr(policy, "pure", False))
    elif reuse and not unit:
        raise ValueError(f"reuse=True needs unit level steps (the walk's next level from the level alone), "
                         f"got level_steps={level_steps!r}")
    parts = [ids for ids in np.array_split(np.arange(len(d)), min(workers, len(d))) if len(ids)]
    part = getattr(policy, "for_lanes", None)   # a policy with per-lane settings hands each worker its part
    args = [(policy if part is None or len(parts) == 1 else part(ids), d[ids], ids, cfg, start, steps, reuse)
            for ids in parts]
    call = (InProcess() if len(parts) == 1 else shared_pool(len(parts))).call
    try:
        call(_score_open, args)
        for until in range(1, episodes + 1):
            outs = call(_score_play, [(until,)] * len(parts))
            if progress:
                progress(f"score {task}: {until * len(d)}/{episodes * len(d)} episodes")
    except BaseException:
        with contextlib.suppress(Exception):
            call(_score_close, [()] * len(parts))
        raise
    call(_score_close, [()] * len(parts))
    j = level_score(task, np.concatenate([o[0] for o in outs]))
    if stats is not None:
        stats["episodes_played"] = int(sum(o[2] for o in outs))
    return (j, np.concatenate([o[1] for o in outs])) if final_x else j


# ----------------------------------------------------------------------------------------------------------
# 9. Command line: motion strip and benchmark
# ----------------------------------------------------------------------------------------------------------
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


def _bench_steps(env, steps: int, seed: int):
    """Step `env` (here or inside a worker) with uniform random actions; (time inside stepSimulation, wall)."""
    rng = np.random.default_rng(seed)
    sim0, t0 = env.sim_seconds, time.perf_counter()
    for _ in range(steps):
        env.step(rng.uniform(0, 1, (env.num_envs, ACT_DIM)))
    return env.sim_seconds - sim0, time.perf_counter() - t0


def _bench_env(lanes: int, workers: int, steps: int, cfg: BalluConfig):
    """Robot-physics-steps/s (200 Hz) of `lanes` lanes per worker, each worker stepping its own lanes:
    (physics only = steps / time inside stepSimulation, env with all per-step work = steps / wall)."""
    n = lanes * workers
    env = BalluEnv(n, cfg) if workers == 1 else VecBallu(n, workers, cfg)
    try:
        env.reset(seed=0, options={"designs": BASELINE, "levels": 10})
        if workers == 1:
            out = [_bench_steps(env, steps, 0)]
        else:
            out = env.run(_bench_steps, [(steps, k) for k in range(workers)])
    finally:
        env.close()
    sim, wall = np.max(np.array(out), axis=0)   # the slowest worker sets the pace
    robot_steps = n * steps * cfg.decimation
    return robot_steps / sim, robot_steps / wall


def _bench_score(designs: int, workers: int, cfg: BalluConfig):
    """Robot-physics-steps/s of `score` (pump gaits of 16 periods, 2 short episodes per design)."""
    periods = np.resize(np.arange(4, 36, 2), designs)
    t0 = time.perf_counter()
    score(PumpGait(periods), np.tile(BASELINE, (designs, 1)), cfg.task, episodes=2, start_level=10,
          workers=workers, cfg=cfg)
    return designs * 2 * cfg.episode_steps * cfg.decimation / (time.perf_counter() - t0)


def bench(lanes: int = 16, workers: int = 2, control_steps: int = 200, repeats: int = 2):
    """Simulator throughput next to references measured in the same run.

    Physics only: the time inside stepSimulation alone while the same robots move under random actions. Env:
    all per-step work (forces, torques, state reads, reward, observation). Rates are robot-physics-steps/s
    at 200 Hz. The reference is PREVIOUS_ROBOT (fixed 8 substeps in worlds of 4 lanes), stepped the same way.
    Each configuration is measured `repeats` times in alternation (this machine drifts +-20 % within minutes)
    and the mean is printed. Pool start-up is paid before the scoring rows (the pool is long-lived, so that is
    how `run_all.py` sees it).
    """
    base = BalluConfig()
    before = replace(base, **PREVIOUS_ROBOT)
    sweep = [b for b in (1, 2, 4, 8, 16) if b <= lanes]
    rows = {}
    for _ in range(repeats):
        for b in sweep:
            rows.setdefault(("layout", b), []).append(_bench_env(lanes, 1, control_steps, replace(base, lanes_per_world=b)))
        rows.setdefault(("before", 1), []).append(_bench_env(lanes, 1, control_steps, before))
        rows.setdefault(("env", workers), []).append(_bench_env(lanes, workers, control_steps, base))
        rows.setdefault(("before", workers), []).append(_bench_env(lanes, workers, control_steps, before))
    short = replace(base, episode_steps=100)
    _bench_score(workers, workers, short)   # start the shared pool
    for _ in range(repeats):
        for w in (1, workers):
            rows.setdefault(("score", w), []).append((_bench_score(lanes * workers, w, short),))
    m = {k: np.mean(v, axis=0) for k, v in rows.items()}
    print(f"layout sweep, {lanes} lanes on 1 core        physics only   env, all per-step work")
    for b in sweep:
        raw, env = m[("layout", b)]
        tag = "   <- BalluConfig.lanes_per_world" if b == base.lanes_per_world else ""
        print(f"  {lanes // b:2d} world(s) of {b:2d} lane(s)            {raw:10,.0f}/s {env:14,.0f}/s{tag}")
    raw1, env1 = m[("layout", base.lanes_per_world)]
    raw2, env2 = m[("env", workers)]
    rawb1, envb1 = m[("before", 1)]
    rawb2, envb2 = m[("before", workers)]
    s1, s2 = m[("score", 1)][0], m[("score", workers)][0]
    print(f"1 core, {lanes} lanes:               physics only {raw1:8,.0f}/s   env {env1:8,.0f}/s")
    print(f"  previous robot (8 substeps):   physics only {rawb1:8,.0f}/s   env {envb1:8,.0f}/s   "
          f"-> default {raw1 / rawb1:.2f}x physics, {env1 / envb1:.2f}x env")
    print(f"{workers} workers, {lanes} lanes each:     physics only {raw2:8,.0f}/s   env {env2:8,.0f}/s")
    print(f"  previous robot (8 substeps):   physics only {rawb2:8,.0f}/s   env {envb2:8,.0f}/s   "
          f"-> default {raw2 / rawb2:.2f}x physics, {env2 / envb2:.2f}x env")
    print(f"score, {lanes * workers} designs:          1 core {s1:8,.0f}/s   {workers} workers {s2:8,.0f}/s")
    print(f"env/physics ratio {env1 / raw1:.2f}   (1 core, all per-step work / stepSimulation alone)")
    print(f"{workers} workers vs 1 core {env2 / env1:.2f}x   (env: each worker steps its own lanes, as ppo.train)")
    print(f"{workers} workers vs 1 core {s2 / s1:.2f}x   (score: each worker plays its designs)")
    print(f"({repeats} alternating repeats each; robot-physics-steps per second at 200 Hz; default: adaptive "
          f"{base.substeps}/{base.substeps_fine} substeps, previous robot: ballu.PREVIOUS_ROBOT)")
    return m


def _main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bench", action="store_true", help="print simulator throughput")
    ap.add_argument("--lanes", type=int, default=16, help="lanes per worker in the bench (>= 1)")
    ap.add_argument("--workers", type=int, default=2, help="worker processes (>= 1)")
    ap.add_argument("--strip", metavar="PNG", help="write a motion strip of one pump-gait episode")
    ap.add_argument("--task", default="obstacle", choices=TASKS)
    ap.add_argument("--level", type=int, default=30, help=f"terrain level of the strip, 0..{MAX_LEVEL}")
    ap.add_argument("--design", type=float, nargs=4, default=BASELINE.tolist(), metavar=DESIGN_NAMES)
    ap.add_argument("--period", type=int, default=12, help="pump gait period in control steps (>= 2)")
    ap.add_argument("--mode", default="sync", choices=("sync", "alternate"), help="pump gait mode")
    args = ap.parse_args(argv)
    if not (args.bench or args.strip):
        ap.error("nothing to do: give --bench and/or --strip PNG (audit and capability: python -m "
                 "experiments.ballu_capability; a learned policy's strip: python -m experiments.ppo_ballu strip)")
    for opt, value, rule, ok in (("--workers", args.workers, ">= 1", args.workers >= 1),
                                 ("--lanes", args.lanes, ">= 1", args.lanes >= 1),
                                 ("--level", args.level, f"in [0, {MAX_LEVEL}]", 0 <= args.level <= MAX_LEVEL),
                                 ("--period", args.period, ">= 2", args.period >= 2)):
        if not ok:
            ap.error(f"{opt} {value} must be {rule}")
    try:
        check_design(args.design, what="--design")
    except ValueError as e:
        ap.error(str(e))
    if args.bench:
        bench(args.lanes, args.workers)
    if args.strip:
        try:
            print("wrote", motion_strip(args.strip, PumpGait(args.period, args.mode), args.task, args.level,
                                        np.array(args.design)))
        except OSError as e:
            ap.error(f"--strip {args.strip!r} cannot be written: {e.strerror}")


if __name__ == "__main__":
    _main()
