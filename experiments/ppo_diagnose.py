"""experiments/ppo_diagnose.py -- how a trained policy fails the obstacle: where it stops, how it jumps.

    python -m experiments.ppo_diagnose POLICY.pt --design gcr=0.839,spcf=0.017 [--levels 10:40:2] [--out strip.png]

Plays one deterministic episode per obstacle level (curriculum off, the policy's mean action, as the score J
plays them) and prints, per level: where the pelvis ends (the curriculum moves up past x = 1.0 m, down short of
0.5 m; the box spans 0.5..1.5 m), how far it got, when it first came within 0.15 m of the box, how many jumps
it tried there (a rise of the lower toe by >= 3 cm above its last low point while within 0.3 m in front of the
box) and the highest toe clearance over the box's height in that zone. Each episode gets a verdict:
  pass         final x > 1.0 (the level would go up)
  short        never within 0.15 m of the box: it stalls before reaching it
  no jump      reached the box, never tried a jump of >= 3 cm there
  too low      jumped, but no toe rose above the box's top edge in front of it
  not onto     a toe rose above the box's top, but no toe ever stood on the box (within 2 cm of its top)
  on, fell     a toe stood on the box, yet the pelvis ended short of 1.0 m (slid or fell back)
--out PNG films the lowest failing level above the lowest passing one (report.strip.motion_strip): where J's walk
stops.
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

import ballu
import ppo
from experiments import args
from report.strip import motion_strip

NEAR, ZONE, JUMP = 0.15, 0.30, 0.03   # m: "at the box", the zone in front of it, a jump's least toe rise


def episode(policy, design, level: int, cfg: ballu.BalluConfig) -> dict:
    """One episode at `level`; what the pelvis and the toes did around the box (see the module docstring)."""
    env = ballu.BalluEnv(1, cfg, curriculum=False)
    g, h = ballu.task_geometry("obstacle"), float(ballu.level_height("obstacle", level))
    obs, _ = env.reset(seed=0, options={"designs": design, "levels": level})
    xs, t_near, jumps, low, over, armed, on_top = [], None, 0, np.inf, -np.inf, True, False
    for t in range(cfg.episode_steps):
        obs, _, term, trunc, info = env.step(policy(obs))
        if term[0] or trunc[0]:   # the lane was reset: its last pelvis x is in the info
            xs.append(float(info["final_x"][0]))
            break
        s = env.read_lanes()
        pos, toe = s.pos, s.toe
        x, toe_z, toe_x = pos[0, 0], toe[0, :, 2].min(), toe[0, :, 0].max()
        on_top |= bool(np.any((toe[0, :, 0] > g["x0"] + 0.01) & (toe[0, :, 0] < g["x1"])
                              & (np.abs(toe[0, :, 2] - h) < 0.02)))
        xs.append(x)
        if t_near is None and toe_x > g["x0"] - NEAR:
            t_near = t * cfg.control_dt
        if g["x0"] - ZONE < toe_x < g["x0"] + 0.05:   # in front of the box, or its front edge
            over = max(over, toe[0, :, 2].max() - h)
            low = min(low, toe_z)
            if armed and toe_z - low >= JUMP:
                jumps, armed = jumps + 1, False
            elif toe_z - low < JUMP / 3:
                armed = True
    env.close()
    final = xs[-1]
    verdict = ("pass" if final > g["up"] else "short" if t_near is None else "no jump" if jumps == 0
               else "too low" if over < 0 and not on_top else "on, fell" if on_top else "not onto")
    return {"level": level, "cm": 100 * h, "final_x": final, "max_x": max(xs), "t_near": t_near, "jumps": jumps,
            "over_cm": 100 * over if np.isfinite(over) else float("nan"), "verdict": verdict}


def diagnose(policy_path: str, design, levels) -> list:
    policy = ppo.load_policy(policy_path)
    cfg = ballu.policy_config(policy, "obstacle")   # the observation it trained with
    return [episode(policy, design, int(lv), cfg) for lv in levels]


def table(rows) -> str:
    out = ["| level (cm) | final x | max x | at box (s) | jumps | best toe over box top (cm) | verdict |",
           "|---|---|---|---|---|---|---|"]
    for r in rows:
        near = "-" if r["t_near"] is None else f"{r['t_near']:.1f}"
        out.append(f"| {r['cm']:.0f} | {r['final_x']:.2f} | {r['max_x']:.2f} | {near} | {r['jumps']} | "
                   f"{r['over_cm']:+.1f} | {r['verdict']} |")
    return "\n".join(out)


def _levels(text: str) -> list:
    try:
        lo, hi, step = (int(v) for v in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} must be LOW:HIGH:STEP (integers)") from None
    if not (0 <= lo <= hi <= ballu.MAX_LEVEL and step >= 1):
        raise argparse.ArgumentTypeError(f"{text!r}: need 0 <= LOW <= HIGH <= {ballu.MAX_LEVEL}, STEP >= 1")
    return list(range(lo, hi + 1, step))


def main(argv=None):
    ap = args.program("python -m experiments.ppo_diagnose", __doc__)
    ap.add_argument("policy", metavar="POLICY.pt")
    ap.add_argument("--design", required=True, type=args.full_design_type, help=args.DESIGN_HELP)
    ap.add_argument("--levels", type=_levels, default=_levels("10:40:2"), help="LOW:HIGH:STEP (default 10:40:2)")
    ap.add_argument("--out", metavar="PNG", help="film the lowest level above a passed one that does not pass")
    a = args.parse(ap, argv)
    try:
        rows = diagnose(a.policy, a.design, a.levels)
    except (OSError, ValueError) as e:
        ap.error(str(e))
    print(table(rows))
    passed = [i for i, r in enumerate(rows) if r["verdict"] == "pass"]
    fail = next((r for r in rows[passed[0]:] if r["verdict"] != "pass"), None) if passed else rows[0]
    if a.out and fail:
        policy = ppo.load_policy(a.policy)
        print("wrote", motion_strip(a.out, policy, "obstacle", fail["level"], a.design, frames=10))


if __name__ == "__main__":
    sys.exit(main())
