"""experiments/ballu_capability.py -- is the simulated robot sound, and what can it do without learning?

  1. the physics audit: random open-loop actions (bang-bang included) on random D3 designs; blow-ups, joint-limit
     excesses and the energy balance (`EnergyAudit`: mechanical energy may never rise above the work done)
  2. capability: small open-loop searches for the highest toe clearance, obstacle and ramp a design reaches;
     lower bounds on what a policy can do, to tell a weak learner from a weak robot

    python -m experiments.ballu_capability --audit 200      # a table per simulator setting (AUDIT_CONFIGS)
    python -m experiments.ballu_capability --capability     # designs x CAPABILITY_CONFIGS x 3 search seeds
    python -m experiments.ballu_capability --floors         # J of the scripted floors (stand, pump gaits)
    python -m experiments.ballu_capability --ceiling obstacle   # the open-loop level on the PPO protocol's designs

Results and their reading: docs/capability/README.md. [ours] throughout: the paper and the facts are silent.
"""
from __future__ import annotations

import sys
import time
from dataclasses import replace

import numpy as np

from ballu import (BALLOON, BASELINE, D2_CENTRE, HARDWARE_DRAG, JOINT_LIMITS, JOINTS, MAX_LEVEL, TABLE_I_HIGH,
                   TABLE_I_LOW, BalluConfig, BalluEnv, PumpGait, check_design, level_score, score, stand,
                   surface_height, task_geometry, to_base_frame)
from experiments import args
from experiments.ballu_bench import PREVIOUS_ROBOT
from runkit.lanes import InProcess, plain_call, shared_pool


def random_actions(rng, n: int, steps: int, hold=(1, 10)) -> np.ndarray:
    """Open-loop test actions (n, steps, 2): each leg holds a value for 1-10 control steps; half of the values
    are bang-bang (0 or 1, the full range at once), half uniform in [0, 1]. [ours]"""
    out = np.empty((n, steps, 2))
    for i in range(n):
        for j in range(2):
            t = 0
            while t < steps:
                h = int(rng.integers(hold[0], hold[1] + 1))
                out[i, t:t + h, j] = float(rng.integers(0, 2)) if rng.uniform() < 0.5 else rng.uniform()
                t += h
    return out


class EnergyAudit:
    """An env monitor: per physics step and lane, the joint-limit excess and the energy balance.

    balance = (E_now - E_start) - W, with E the mechanical energy (kinetic + gravitational potential of every
    link, balloon included) and W the work done on the robot by the knee torques (tau * dq) and the balloon
    force (buoyancy + drag, F . dx of its centre); tau holds every joint's applied torque (JOINTS order: the
    passive joints' damping and the knees'). Contacts, joint limits and friction may only take energy
    away, so the balance must never rise; `rise` is its largest rise above its running minimum (J).
    Lanes flagged in `alive` = False (blown up and reset) are no longer audited.
    """

    def __init__(self, env):
        self.env, self.g = env, env.cfg.gravity
        self.dyn = [[(env.client(i).getDynamicsInfo(b, k)[0], np.array(env.client(i).getDynamicsInfo(b, k)[2]))
                     for k in range(-1, 5)] for i, b in enumerate(env.bodies)]
        n = env.num_envs
        self.alive = np.ones(n, bool)
        self.limit_excess, self.rise = np.zeros(n), np.zeros(n)
        self.balance, self.low, self.work = np.zeros(n), np.zeros(n), np.zeros(n)   # work: sum of |W| per step
        self.prev = [self._state(i) for i in range(n)]

    def _state(self, i):
        p, b = self.env.client(i), self.env.bodies[i]
        pos, orn = p.getBasePositionAndOrientation(b)
        lin, ang = p.getBaseVelocity(b)
        frames = [(pos, orn, lin, ang)] + [(s[0], s[1], s[6], s[7]) for s in p.getLinkStates(b, range(5), 1)]
        energy = 0.0
        for (m, inertia), (x, q, v, w) in zip(self.dyn[i], frames):
            w_body = to_base_frame(np.array([q]), np.array([w]))[0]
            energy += 0.5 * m * float(np.dot(v, v)) + 0.5 * float(inertia @ w_body ** 2) + m * self.g * x[2]
        jq = np.array([s[0] for s in p.getJointStates(b, JOINTS)])
        return energy, jq, np.array(frames[1 + BALLOON][0])

    def __call__(self, env):
        for i in np.flatnonzero(self.alive):
            e, jq, xb = self._state(i)
            e0, jq0, xb0 = self.prev[i]
            tau, force = env._applied[i]
            work = float(np.dot(tau, jq - jq0)) + float(np.dot(force, xb - xb0))
            self.balance[i] += (e - e0) - work
            self.work[i] += abs(work)
            self.low[i] = min(self.low[i], self.balance[i])
            self.rise[i] = max(self.rise[i], self.balance[i] - self.low[i])
            excess = np.maximum(JOINT_LIMITS[:, 0] - jq, jq - JOINT_LIMITS[:, 1]).max()
            self.limit_excess[i] = max(self.limit_excess[i], excess)
            self.prev[i] = (e, jq, xb)


def play_open_loop(designs, actions, task: str = "obstacle", level=0, cfg: BalluConfig | None = None,
                   audit: bool = False) -> dict:
    """Play per-lane action sequences (n, T, 2) open loop for one episode of T control steps.

    Returns per lane: final pelvis x, peak toe clearance with both feet off the surface (sampled at 20 Hz,
    from the first touch-down on),
    blow-up flags, and with `audit` the largest joint-limit excess (rad) and energy rise (J) of EnergyAudit.
    """
    actions = np.asarray(actions, dtype=float)
    n, steps = actions.shape[:2]
    cfg = replace(cfg or BalluConfig(), task=task, episode_steps=steps + 1)   # no time-limit reset inside
    env = BalluEnv(n, cfg, curriculum=False)
    try:
        env.reset(seed=0, options={"designs": designs, "levels": level})
        mon = env.monitor = EnergyAudit(env) if audit else None
        alive, landed, peak = np.ones(n, bool), np.zeros(n, bool), np.zeros(n)
        for t in range(steps):
            term = env.step(actions[:, t])[2]
            alive &= ~term                 # a blown-up lane was reset: nothing after it counts
            if mon is not None:
                mon.alive &= ~term
            s = env.read_lanes()
            pos, toe = s.pos, s.toe
            clear = (toe[:, :, 2] - surface_height(task, toe[:, :, 0], env.levels[:, None])).min(axis=1)
            landed |= clear < 0.01         # the spawn drop (feet 0.2-0.3 m up at t = 0) is no jump
            peak = np.where(alive & landed, np.maximum(peak, clear), peak)
        out = {"final_x": np.where(alive, pos[:, 0], np.nan), "peak_clearance": peak, "blowup": ~alive}
        if mon is not None:
            out.update(limit_excess=mon.limit_excess, energy_rise=mon.rise)
        return out
    finally:
        env.close()


def _play_chunks(designs, actions, task, level, cfg, audit=False, workers=2):
    """play_open_loop with the lanes split over `workers` processes of the shared pool; results joined."""
    n = len(actions)
    designs = np.broadcast_to(check_design(designs), (n, 4))
    levels = np.broadcast_to(np.asarray(level), (n,))
    parts = np.array_split(np.arange(n), max(1, min(workers, n)))
    args = [(play_open_loop, (designs[ids], actions[ids], task, levels[ids], cfg, audit)) for ids in parts]
    outs = (InProcess() if len(parts) == 1 else shared_pool(len(parts))).call(plain_call, args)
    return {k: np.concatenate([o[k] for o in outs]) for k in outs[0]}


def stability_audit(episodes: int = 200, steps: int = 400, cfg: BalluConfig | None = None, seed: int = 0,
                    workers: int = 2, task: str = "obstacle") -> dict:
    """Random open-loop rollouts on random designs over the whole D3 box and the baseline (every 10th).

    Counts blow-ups (the facts' early-end rule: non-finite state, pelvis speed > 10 m/s or z > 5 m) and
    joint-limit excesses > 0.05 rad, and reports the largest energy rise (EnergyAudit). Level 10 terrain:
    the feet meet the ground, the box face and its top.
    """
    rng = np.random.default_rng(seed)
    d3 = TABLE_I_LOW + (TABLE_I_HIGH - TABLE_I_LOW) * rng.uniform(size=(episodes, 4))   # D3 box [paper]
    d3[:, 1] = d3[:, 0]                                       # D3: l_f = l_t = l
    d3[::10] = BASELINE
    acts = random_actions(rng, episodes, steps)
    out = _play_chunks(d3, acts, task, 10, cfg, audit=True, workers=workers)
    out["designs"] = d3
    return out


AUDIT_CONFIGS = {   # name -> BalluConfig changes
    "default: no drag, adaptive 4/8 substeps": {},
    "option: balloon drag 0.4 v^2": {"drag_coef": HARDWARE_DRAG},
    "fixed 8 substeps": {"substeps": 8, "substeps_fine": 8},
    "fixed 4 substeps": {"substeps_fine": 4},
    "previous robot (drag, 45 deg preload, fixed 8 substeps)": PREVIOUS_ROBOT,
}


def audit_table(episodes: int = 200, workers: int = 2) -> str:
    """`python -m experiments.ballu_capability --audit N`: blow-ups, joint-limit excesses and energy rises of
    each AUDIT_CONFIGS row."""
    rows = ["| simulator | blow-ups | episodes with a joint > 0.05 rad past its limit | largest excess | "
            "largest energy rise |", "|---|---|---|---|---|"]
    for name, change in AUDIT_CONFIGS.items():
        o = stability_audit(episodes, cfg=replace(BalluConfig(), **change), workers=workers)
        ok = ~o["blowup"]
        rows.append(f"| {name} | {o['blowup'].sum()}/{episodes} | {(o['limit_excess'][ok] > 0.05).sum()} | "
                    f"{o['limit_excess'][ok].max():.3f} rad | {1000 * o['energy_rise'][ok].max():.1f} mJ |")
        print(rows[-1], flush=True)
    return "\n".join(rows)


CAPABILITY_DESIGNS = {                               # (l_f, l_t, gcr, spcf)
    "baseline": tuple(BASELINE),
    "D2 centre": tuple(D2_CENTRE),
    "paper optimum (gcr 0.88, spcf 0.008)": (0.45, 0.45, 0.88, 0.008),
    "gcr 0.90, spcf 0.1": (0.45, 0.45, 0.90, 0.1),
}


def gait_actions(params, steps: int) -> np.ndarray:
    """Open-loop periodic gaits (n, steps, 2) from params in [0, 1]^5 per lane: period 4-40 control steps,
    duty 0.2-0.8, right leg's phase lag (0 = hop, 0.5 = walk), low action 0-0.5, high action 0.5-1."""
    u = np.clip(np.asarray(params, dtype=float), 0, 1)
    period, duty, lag = 4 + 36 * u[:, 0:1], 0.2 + 0.6 * u[:, 1:2], u[:, 2:3]
    low, high = 0.5 * u[:, 3:4], 0.5 + 0.5 * u[:, 4:5]
    phase = np.arange(steps)[None] / period
    left = np.where(phase % 1.0 < duty, high, low)
    right = np.where((phase - lag) % 1.0 < duty, high, low)
    return np.stack([left, right], axis=-1)


# PumpGait(period, mode) for periods 4, 8, ..., 40 and both modes, as gait_actions parameters
PUMP_GAITS = np.array([[(p - 4) / 36, 0.5, lag, 0.0, 1.0] for lag in (0.0, 0.5) for p in range(4, 41, 4)])


def _search_level(design, task, cfg, rng, pop, iters, workers):
    """Highest level an open-loop gait clears (curriculum 'up' rule on the final pelvis x after 20 s).

    Galloping search from level 0: after a level is cleared try 1, 2, 4, ... levels higher; after a failure
    (two populations in a row, the second refit on the first) bisect between the highest cleared and the
    lowest failed level. At each level `pop` gaits play one
    episode: half drawn around a cross-entropy mean (refit on the gaits that got furthest), a quarter around
    the best gait that cleared so far, a quarter uniform; the first population holds the pump gaits. Returns
    (level, best gait params); -1 if not even level 0 was cleared."""
    up = task_geometry(task)["up"]
    ok, fail, best, jump, retry, first = -1, MAX_LEVEL + 1, None, 1, None, True
    mean, std = np.full(5, 0.5), np.full(5, 0.35)
    for _ in range(iters):
        if retry is not None:
            level = retry                                           # a second population at a failed level
        elif fail > MAX_LEVEL:
            level = min(ok + jump, MAX_LEVEL) if ok >= 0 else 0    # gallop up from level 0
        else:
            level = (ok + fail) // 2                                # bisect
        q = pop // 4
        around = best if best is not None else mean
        params = np.clip(np.concatenate([mean + std * rng.standard_normal((pop - 2 * q, 5)),
                                         around + 0.1 * rng.standard_normal((q, 5)),
                                         rng.uniform(size=(q, 5))]), 0, 1)
        if first:                          # the pump gaits (full-range square waves, hop and walk) seed it
            params = np.concatenate([PUMP_GAITS, params])[:max(pop, len(PUMP_GAITS))]
            first = False
        if best is not None:
            params[0] = best
        x = np.nan_to_num(_play_chunks(design, gait_actions(params, cfg.episode_steps), task, level, cfg,
                                       workers=workers)["final_x"], nan=-9.0)
        elite = params[np.argsort(-x)[:max(2, pop // 4)]]
        mean, std = elite.mean(0), elite.std(0) + 0.05
        if (x > up).any():
            ok, best, jump, retry = level, params[np.argmax(x)], 2 * jump, None
        elif retry is None:
            retry = level                  # one failed population is weak evidence: try once more
        else:
            fail, jump, retry = level, 1, None
        if fail - ok <= 1 or ok == MAX_LEVEL:
            break
    return ok, best


def _search_clearance(design, cfg, rng, pop, iters, workers, seconds=6.0, segment=5):
    """Highest toe clearance with both feet off the ground (flat ground, 6 s): cross-entropy over per-leg
    bang-bang sequences of `segment` control steps, seeded with crouch-then-release scripts."""
    steps = int(seconds / cfg.control_dt)
    nseg = -(-steps // segment)
    prob, best = np.full((nseg, 2), 0.5), 0.0
    for it in range(iters):
        bits = (rng.uniform(size=(pop, nseg, 2)) < prob).astype(float)
        if it == 0:                        # crouch for 0.25-2 s, then release (both legs)
            for j, k in enumerate(np.linspace(1, min(nseg - 1, int(2.0 / cfg.control_dt / segment)), pop // 4)):
                bits[j] = 0.0
                bits[j, :int(k)] = 1.0
        acts = np.repeat(bits, segment, axis=1)[:, :steps]
        peak = _play_chunks(design, acts, "obstacle", 0, cfg, workers=workers)["peak_clearance"]
        best = max(best, float(peak.max()))
        elite = bits[np.argsort(-peak)[:max(2, pop // 6)]]
        prob = np.clip(elite.mean(0), 0.05, 0.95)
    return best


def capability(design, cfg: BalluConfig | None = None, seed: int = 0, pop: int = 16, iters: int = 14,
               workers: int = 2) -> dict:
    """What the robot can do open loop (no learning): peak toe clearance (m), the highest obstacle level it
    clears and the highest ramp level it climbs, each found by a small search (64 + 2 x <= 224 rollouts).
    A search gives lower bounds: a better open-loop gait, and a feedback policy, may do more. [ours]"""
    cfg = cfg or BalluConfig()
    rng = np.random.default_rng(seed)
    clear = _search_clearance(design, cfg, rng, pop, 4, workers)
    obs_level, _ = _search_level(design, "obstacle", cfg, rng, pop, iters, workers)
    ramp_level, _ = _search_level(design, "ramp", cfg, rng, pop, iters, workers)
    return {"clearance_m": clear, "obstacle_level": obs_level, "ramp_level": ramp_level,
            "obstacle_cm": float(level_score("obstacle", max(obs_level, 0))) if obs_level >= 0 else 0.0,
            "ramp_deg": float(level_score("ramp", max(ramp_level, 0))) if ramp_level >= 0 else 0.0}


CAPABILITY_CONFIGS = {"default: no drag": {}, "option: balloon drag 0.4 v^2": {"drag_coef": HARDWARE_DRAG}}


def capability_table(designs=("baseline", "paper optimum (gcr 0.88, spcf 0.008)"), seeds=(0, 1, 2),
                     workers: int = 2, progress=print) -> str:
    """`python -m experiments.ballu_capability --capability`: each design under each CAPABILITY_CONFIGS
    simulator, the median over search seeds (each seed's value in brackets), beside the paper."""
    rows = ["| design | simulator | toe clearance, m | obstacle cleared, cm | ramp climbed, deg |",
            "|---|---|---|---|---|"]
    t0 = time.time()
    for name in designs:
        for sim, change in CAPABILITY_CONFIGS.items():
            cs = [capability(np.array(CAPABILITY_DESIGNS[name]), replace(BalluConfig(), **change), seed=s,
                             workers=workers) for s in seeds]
            cells = []
            for key, fmt in (("clearance_m", ".2f"), ("obstacle_cm", ".0f"), ("ramp_deg", ".1f")):
                v = [c[key] for c in cs]
                cells.append(f"{np.median(v):{fmt}} ({', '.join(f'{x:{fmt}}' for x in v)})")
            rows.append(f"| {name} | {sim} | " + " | ".join(cells) + " |")
            progress(f"capability: {rows[-1]}  [{time.time() - t0:.0f} s]")
    rows.append("| paper, its simulation | | | baseline 14.2 (mean J); optimised designs 45-54 | baseline 25.1 "
                "(mean J); optimised 36 |")
    rows.append("| paper, hardware | | | 8 (baseline); 24 (gcr 0.86, spcf 0.008) | |")
    return (f"Open-loop search (no learning), median over search seeds {list(seeds)} with each seed's value in "
            f"brackets; lower bounds on what a policy can do.\n\n" + "\n".join(rows))


def ceiling_table(task: str, seed: int = 0, pop: int = 16, iters: int = 14, workers: int = 2,
                  progress=print) -> str:
    """`--ceiling TASK`: the highest level an open-loop gait clears (`_search_level`) on each of the PPO
    protocol's held-out designs, so that a policy's J there can be read against what the design itself allows:
    a policy far below it is a weak learner, one near it a weak design. One search seed (a lower bound)."""
    from experiments.ppo_protocol import protocol_designs
    rows = ["| design | gcr | spcf | open-loop level cleared | in the score's unit |", "|---|---|---|---|---|"]
    t0 = time.time()
    for i, d in enumerate(protocol_designs()):
        level, _ = _search_level(d, task, BalluConfig(task=task), np.random.default_rng(seed), pop, iters, workers)
        unit = f"{level_score(task, level):.1f}" if level >= 0 else "-"
        rows.append(f"| {i} | {d[2]:.3f} | {d[3]:.3f} | {level} | {unit} |")
        progress(f"ceiling: {rows[-1]}  [{time.time() - t0:.0f} s]")
    return (f"{task}: open-loop search (search seed {seed}) on the PPO protocol's held-out D2 designs; level -1: "
            f"not even level 0 cleared.\n\n" + "\n".join(rows))


FLOOR_DESIGNS = ("baseline", "paper optimum (gcr 0.88, spcf 0.008)")


def floors_table(designs=FLOOR_DESIGNS, workers: int = 2) -> str:
    """`--floors`: the score J (20 episodes from level 28 / 40) of the scripted floors on each design and task:
    `stand` (zero action) and the best of the 20 pump gaits (both knees together or alternating, periods
    4, 8, ..., 40 control steps). A learned policy that scores no higher has learned nothing a script cannot do."""
    gaits = [(p, m) for m in ("sync", "alternate") for p in range(4, 41, 4)]
    rows = ["| design | task | stand | best pump gait | its period, mode |", "|---|---|---|---|---|"]
    for name in designs:
        d = np.array(CAPABILITY_DESIGNS[name])
        for task in ("obstacle", "ramp"):
            j_stand = float(score(stand, d[None], task, workers=1)[0])
            pump = PumpGait([p for p, _ in gaits], [m for _, m in gaits])
            j = score(pump, np.tile(d, (len(gaits), 1)), task, workers=workers)
            k = int(np.argmax(j))
            rows.append(f"| {name} | {task} | {j_stand:.1f} | {j[k]:.1f} | {gaits[k][0]}, {gaits[k][1]} |")
            print(rows[-1], flush=True)
    return "J in cm (obstacle) or deg (ramp).\n\n" + "\n".join(rows)


def main(argv=None):
    ap = args.program("python -m experiments.ballu_capability", __doc__)
    ap.add_argument("--audit", type=int, metavar="EPISODES", help="random open-loop stability and energy audit")
    ap.add_argument("--capability", action="store_true", help="open-loop search: what the robot can do")
    ap.add_argument("--floors", action="store_true", help="J of the scripted floors (stand, pump gaits)")
    ap.add_argument("--ceiling", choices=("obstacle", "ramp"), metavar="TASK",
                    help="open-loop level on each PPO protocol design (obstacle or ramp)")
    args.add_workers(ap)
    a = args.parse(ap, argv)
    if a.audit is not None and a.audit < 1:
        ap.error(f"--audit {a.audit}: the number of episodes must be >= 1")
    if a.workers < 1:
        ap.error(f"--workers {a.workers} must be >= 1")
    if not (a.audit or a.capability or a.floors or a.ceiling):
        ap.error("nothing to do: give --audit EPISODES, --capability, --floors and/or --ceiling TASK")
    if a.audit:
        print(audit_table(a.audit, a.workers))
    if a.capability:
        print(capability_table(workers=a.workers))
    if a.floors:
        print(floors_table(workers=a.workers))
    if a.ceiling:
        print(ceiling_table(a.ceiling, workers=a.workers))


if __name__ == "__main__":
    sys.exit(main())
