"""experiments/stay_band.py -- why do our obstacle episodes end in the stay band, and what does J credit there?

J's curriculum keeps a level when an episode ends with the pelvis between x = 0.5 (the box face) and 1.0 m (the
box's middle) [facts]. This study asks where our robot is when an episode ends there, whether a difference
between our robot and the authors' puts it there, and what J becomes when only clearing counts (the strict rule,
ballu.curriculum_update).

    python -m experiments.stay_band ends docs/overnight/seed0 docs/overnight/seed1 --out ~/runs/stay/ends.json
    python -m experiments.stay_band pressed --out ~/runs/stay/pressed.json      # scripted pumps into the box
    python -m experiments.stay_band table ~/runs/stay/ends.json ~/runs/stay/pressed.json

`ends` plays each run's baseline-design policy on the baseline design and its e2e MLP (obstacle D2) on the PPO
protocol's 12 held-out designs, J's 20-episode walk from level 28 under the facts' rule, once per simulator
variant (VARIANTS: ours, and one difference to the authors' robot or simulation at a time), and records where
each episode ends: short of the face; in the band touching the box top ("top"), only its face or front edge
("face": pressed against it, hooked on the edge or leaning over it) or no box ("free"); or past 1.0 m
("cleared"). `pressed` plays scripted pump gaits (no learning) into boxes of several heights and records the final
pelvis x of every robot that ends touching the box. Results: docs/stay_band/README.md. [ours] throughout.
"""
from __future__ import annotations

import json
import os
import sys
import time
import xml.etree.ElementTree as ET
from contextlib import contextmanager
from dataclasses import replace

import numpy as np

import ballu
from experiments import args

# ----------------------------------------------------------------------------------------------------------
# 1. The variants: our robot, and one difference to the authors' at a time (docs/facts.md, docs/stay_band)
# ----------------------------------------------------------------------------------------------------------
# The robot their experiments used (their morphology generator) has our legs, root, masses and frictions; these
# are the differences left, each an option of ballu.BalluConfig or, for the older hand-made robot, a URDF edit.
VARIANTS = {
    "ours": {},
    "older_legs": {"legs": "original"},                    # original.urdf: tibia collider 13-65 %, no electronics
    "drag": {"drag_coef": ballu.HARDWARE_DRAG},            # a balloon drag 0.4 v^2 (an early branch of their fork)
    "quirk_torque": {"quirk_buoyancy_torque": True},       # their buoyancy's extra uprighting torque
    "solver4": {"solver_iterations": 4},                    # their solver's 4 position iterations
    "no_balloon_contact": {"legs": "no_balloon"},          # the balloon touching nothing (theirs collides)
}


def older_legs(urdf: str, design) -> str:
    """Our URDF with the legs' colliders of their older hand-made robot (original.urdf): the tibia's cylinder
    covers 0.05-0.25 m of its 0.385 m (13-65 % of l_t here), no collider on the electronics, the foot sphere at
    the tibia's tip. Masses and visuals unchanged."""
    root, l_t = ET.fromstring(urdf), float(design[1])
    for link in root.iter("link"):
        if not link.get("name").startswith("tibia"):
            continue
        cols = link.findall("collision")
        tibia, electronics, foot = cols
        lo, hi = 0.05 / 0.385 * l_t, 0.25 / 0.385 * l_t
        tibia.find("origin").set("xyz", f"0 0 {-(lo + hi) / 2:.6f}")
        tibia.find("geometry/cylinder").set("length", f"{hi - lo:.6f}")
        link.remove(electronics)
        foot.find("origin").set("xyz", f"0 0 {-l_t:.6f}")
    return ET.tostring(root, encoding="unicode")


def no_balloon(urdf: str, design) -> str:
    """Our URDF with the balloon's collider removed (a control: does the balloon hold our robot back?)."""
    root = ET.fromstring(urdf)
    for link in root.iter("link"):
        if link.get("name") == "balloon":
            for c in link.findall("collision"):
                link.remove(c)
    return ET.tostring(root, encoding="unicode")


EDITS = {"original": older_legs, "no_balloon": no_balloon}


@contextmanager
def variant(name: str, cfg: ballu.BalluConfig):
    """The simulator settings of VARIANTS[name], and its URDF edit in force while inside (this process only)."""
    opts = dict(VARIANTS[name])
    edit = EDITS.get(opts.pop("legs", None))
    plain = ballu.robot_urdf
    if edit is not None:
        ballu.robot_urdf = lambda design, c=ballu.BalluConfig(): edit(plain(design, c), design)
    try:
        yield replace(cfg, **opts)
    finally:
        ballu.robot_urdf = plain


# ----------------------------------------------------------------------------------------------------------
# 2. Where an episode ends: J's walk, every episode's end state
# ----------------------------------------------------------------------------------------------------------
ENDS = ("short", "face", "top", "free", "cleared")


def box_contact(env: ballu.BalluEnv, levels) -> np.ndarray:
    """Each lane's contact with its box (an index of ENDS): "top" if the robot touches the box's top face (a
    contact point 5 mm or more behind the face, within 5 mm of the top), else "face" if it touches the box at all
    (its face or front edge), else "free"."""
    h, out = ballu.level_height("obstacle", levels), np.full(env.num_envs, 3)
    for i in range(env.num_envs):
        pts = [c[5] for c in env._world[i].p.getContactPoints(env.bodies[i], env.terrain[i])]
        out[i] = 2 if any(p[0] >= 0.505 and p[2] >= h[i] - 0.005 for p in pts) else 1 if pts else 3
    return out


def end_class(final_x, contact) -> np.ndarray:
    """An episode's end (ENDS): short, cleared, or in the band as its box contact says."""
    x = np.asarray(final_x)
    return np.where(x > 1.0, 4, np.where(x < 0.5, 0, contact))


def walk_ends(policy, designs, cfg: ballu.BalluConfig, episodes: int = 20, start: int = 28) -> dict:
    """J's walk (facts' rule unless cfg.strict) of `policy` on each design, one lane each, in this process:
    each episode's level, final x and end class (ENDS), and J. As ballu.score plays it (whole episodes from
    reset seed 0, one world per lane), without its replay of known levels."""
    env = ballu.BalluEnv(len(designs), replace(cfg, lanes_per_world=1), curriculum=True)
    obs, _ = env.reset(seed=0, options={"designs": np.asarray(designs), "levels": start})
    out = {k: np.zeros((len(designs), episodes)) for k in ("level", "x", "end")}
    try:
        for e in range(episodes):
            out["level"][:, e] = env.levels
            for t in range(cfg.episode_steps):
                if t == cfg.episode_steps - 1:   # the contacts one step before the end (the last step resets)
                    contact = box_contact(env, env.levels)
                obs, _, _, _, info = env.step(policy(obs))
            out["x"][:, e] = info["final_x"]
            out["end"][:, e] = end_class(info["final_x"], contact)
        out["J"] = ballu.level_score("obstacle", env.levels)
    finally:
        env.close()
    return {k: v.tolist() for k, v in out.items()}


PROTOCOL_DESIGNS = 12   # the PPO protocol's held-out D2 designs (experiments.ppo_protocol)


def protocol_designs() -> np.ndarray:
    from experiments.ppo_protocol import protocol_designs as held_out
    return held_out(PROTOCOL_DESIGNS)


def cmd_ends(a) -> None:
    from experiments import use
    runs, res = a.runs, {}
    if os.path.exists(a.out):
        res = json.load(open(a.out))
    designs = protocol_designs()
    for run in runs:
        jobs = [("baseline", use.resolve([run, "baseline", "obstacle-d2"]).policy, ballu.BASELINE[None]),
                ("mlp", use.resolve([run, "mlp", "obstacle-d2"]).policy, designs)]
        for name in a.variants.split(","):
            for method, pol, d in jobs:
                key = f"{run}|{method}|{name}"
                if key in res:
                    continue
                t0 = time.time()
                with variant(name, ballu.policy_config(pol, "obstacle")) as cfg:
                    res[key] = walk_ends(pol, d, cfg)
                print(f"{key}: J {np.mean(res[key]['J']):.1f} cm, ends {summary(res[key])}, "
                      f"{time.time() - t0:.0f} s", flush=True)
                with open(a.out + ".tmp", "w") as fh:
                    json.dump(res, fh)
                os.replace(a.out + ".tmp", a.out)


def summary(r: dict) -> str:
    end = np.asarray(r["end"]).ravel()
    return ", ".join(f"{n} {np.mean(end == i):.0%}" for i, n in enumerate(ENDS))


# ----------------------------------------------------------------------------------------------------------
# 3. A scripted robot pressed against the box: where does its pelvis end?
# ----------------------------------------------------------------------------------------------------------
PRESS_DESIGNS = np.array([ballu.BASELINE, [0.45, 0.45, 0.80, 0.01], [0.45, 0.45, 0.88, 0.008],
                          [0.30, 0.30, 0.80, 0.01], [0.55, 0.55, 0.80, 0.01]])
PRESS_LEVELS = (10, 20, 30, 40, 50)
PRESS_GAITS = [(p, m) for p in (6, 10, 16, 24) for m in ("sync", "alternate")]


def pressed(cfg: ballu.BalluConfig) -> dict:
    """Every pump gait x design x level for one episode: the final pelvis x, and whether the robot ends touching
    its box (a contact point between any of its links and the box)."""
    d = np.repeat(PRESS_DESIGNS, len(PRESS_LEVELS), axis=0)
    lv = np.tile(PRESS_LEVELS, len(PRESS_DESIGNS))
    out = {"x": [], "touch": [], "level": [], "design": [], "gait": []}
    for period, mode in PRESS_GAITS:
        gait = ballu.PumpGait(period, mode)
        env = ballu.BalluEnv(len(d), replace(cfg, lanes_per_world=1), curriculum=False)
        obs, _ = env.reset(seed=0, options={"designs": d, "levels": lv})
        for t in range(cfg.episode_steps):
            if t == cfg.episode_steps - 1:
                touch = [bool(w.p.getContactPoints(env.bodies[i], env.terrain[i]))
                         for i, w in enumerate(env._world)]
            obs, _, _, _, info = env.step(gait(obs))
        env.close()
        out["x"] += info["final_x"].tolist()
        out["touch"] += touch
        out["level"] += lv.tolist()
        out["design"] += d.tolist()
        out["gait"] += [f"{period}-{mode}"] * len(d)
    return out


def cmd_pressed(a) -> None:
    res = json.load(open(a.out)) if os.path.exists(a.out) else {}
    for name in a.variants.split(","):
        if name in res:
            continue
        t0 = time.time()
        with variant(name, ballu.BalluConfig(obs="paper")) as cfg:
            res[name] = pressed(cfg)
        x, touch = np.array(res[name]["x"]), np.array(res[name]["touch"])
        print(f"{name}: {touch.sum()} of {len(x)} end touching the box; their final x: median "
              f"{np.median(x[touch]):.2f} m, in the band {np.mean((x[touch] >= 0.5) & (x[touch] <= 1.0)):.0%}, "
              f"{time.time() - t0:.0f} s", flush=True)
        with open(a.out, "w") as fh:
            json.dump(res, fh)


# ----------------------------------------------------------------------------------------------------------
# 4. Rescoring committed runs: every obstacle method under the facts' rule and the strict one, on this machine
# ----------------------------------------------------------------------------------------------------------
METHODS = ("baseline", "mlp", "moe", "ges", "mlp_matched")   # experiments.use's names; "baseline": at its design
RULES = ("facts", "strict")


def test_designs(run: str, sp: str, space) -> list:
    """The run's obstacle test designs of one space, in its test_scores.csv order (Table II's designs)."""
    import csv
    from experiments.args import Design
    with open(os.path.join(run, "test_scores.csv"), newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r["task"] == "obstacle" and r["space"] == sp]
    full = np.array([[float(r[n]) for n in ballu.DESIGN_NAMES] for r in rows])
    theta = full[:, [ballu.SPACE_NAMES.index(n) if n != "l" else 0 for n in space.names]]
    return [Design(f"test {i}", th, f) for i, (th, f) in enumerate(zip(theta, full))]


def cmd_rescore(a) -> None:
    """J of every obstacle method of each run under both rules, resumable (a JSON of finished score sets)."""
    from experiments import use
    res = json.load(open(a.out)) if os.path.exists(a.out) else {}
    order = [(sp, m, run) for sp in ("d2", "d3") for m in METHODS for run in a.runs if sp == "d2" or m != "baseline"]
    for sp, method, run in order:   # the baselines, then D2, then D3: the tables fill cell by cell across runs
        try:
            t = use.resolve([run, method, f"obstacle-{sp}"], workers=a.workers)
        except use.UseError as e:   # a run without that method (quick has no step-matched MLP)
            print(f"{run} {method} {sp}: skipped ({e})", flush=True)
            continue
        designs = [args.design_arg("baseline", t.space)] if method == "baseline" else test_designs(run, sp, t.space)
        for rule in RULES:
            key = f"{run}|{sp}|{method}|{rule}"
            if key in res:
                continue
            t0 = time.time()
            rows = use.score(t, designs, workers=a.workers, rule=rule)
            res[key] = {"J": [r["J"] for r in rows], "x": [r["x"] for r in rows],
                        "designs": [d.full.tolist() for d in designs]}
            print(f"{key}: J {np.mean(res[key]['J']):.1f} cm over {len(rows)} designs, {time.time() - t0:.0f} s",
                  flush=True)
            with open(a.out + ".tmp", "w") as fh:
                json.dump(res, fh)
            os.replace(a.out + ".tmp", a.out)


def cmd_protocol(a) -> None:
    """J under both rules and the share of cleared episodes of PPO protocol runs' best policies
    (experiments.ppo_protocol: FOLDER/SETTING/obstacle/seedS/result_<steps>.json), on the protocol's 12 designs
    or (--design) one design, resumable."""
    import ppo
    res = json.load(open(a.out)) if os.path.exists(a.out) else {}
    designs = protocol_designs() if a.design is None else args.full_design(a.design)[None]
    for folder in a.folders:
        for setting in a.settings.split(","):
            for seed_dir in sorted(glob_dirs(os.path.join(folder, setting, "obstacle"))):
                for m in a.milestones:
                    path = os.path.join(seed_dir, f"result_{m}.json")
                    if not os.path.exists(path):
                        continue
                    best = os.path.join(seed_dir, json.load(open(path)).get("best_file", f"policy_{m}.pt"))
                    pol = ppo.load_policy(best)
                    for rule in RULES:
                        key = f"{seed_dir}|{m}|{rule}"
                        if key in res:
                            continue
                        j, x = ballu.score(pol, designs, "obstacle", workers=a.workers, final_x=True,
                                           strict=rule == "strict")
                        res[key] = {"J": j.tolist(), "x": x.tolist(), "policy": best}
                        print(f"{key}: J {j.mean():.1f} cm, cleared / band / short {outcome_shares(x)}", flush=True)
                        with open(a.out + ".tmp", "w") as fh:
                            json.dump(res, fh)
                        os.replace(a.out + ".tmp", a.out)


def glob_dirs(path: str) -> list:
    return [os.path.join(path, d) for d in os.listdir(path)] if os.path.isdir(path) else []


def cmd_protocol_table(a) -> None:
    """Per setting and milestone: J (facts' rule), J (strict), the cleared share of the facts' walk, mean +- SE
    over seeds."""
    res = json.load(open(a.protocol))
    rows = {}
    for key, r in res.items():
        seed_dir, m, rule = key.split("|")
        setting = os.path.basename(os.path.dirname(os.path.dirname(seed_dir)))
        rows.setdefault((setting, int(m)), {}).setdefault(os.path.basename(seed_dir), {})[rule] = r
    print("| setting | steps | seeds | J, facts' rule | J, strict | cleared (facts' walk) | cleared (strict walk) |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for (setting, m), seeds in sorted(rows.items()):
        done = [s for s in seeds.values() if len(s) == 2]
        cells = [mean_se([np.mean(s[r]["J"]) for s in done]) for r in RULES]
        clear = [mean_se([100 * cleared(s[r]["x"]) for s in done]) + " %" for r in RULES]
        print(f"| {setting} | {m:,} | {len(done)} | {cells[0]} | {cells[1]} | {clear[0]} | {clear[1]} |")


def cleared(xs) -> float:
    o = ballu.episode_outcome("obstacle", np.asarray(xs, dtype=float)).ravel()
    return float(np.mean(o[o >= 0] == 2))


def mean_se(v) -> str:
    v = np.asarray(v, dtype=float)
    return f"{v[0]:.1f}" if len(v) == 1 else f"{v.mean():.1f} +- {v.std(ddof=1) / np.sqrt(len(v)):.1f}"


# ----------------------------------------------------------------------------------------------------------
# 5. The tables
# ----------------------------------------------------------------------------------------------------------
def cmd_table(a) -> None:
    ends = json.load(open(a.ends))
    print("| run | policy | variant | J, cm | " + " | ".join(ENDS) + " |")
    print("| --- | --- | --- | --- | " + "--- | " * len(ENDS))
    for key, r in ends.items():
        run, method, name = key.split("|")
        end = np.asarray(r["end"]).ravel()
        cells = " | ".join(f"{np.mean(end == i):.0%}" for i in range(len(ENDS)))
        print(f"| {short(run)} | {method} | {name} | {np.mean(r['J']):.1f} | {cells} |")
    if a.pressed:
        res = json.load(open(a.pressed))
        print("\n| variant | robots touching the box at the end | their final pelvis x: median [10 %, 90 %] | "
              "in the band |")
        print("| --- | --- | --- | --- |")
        for name, r in res.items():
            x, touch = np.array(r["x"]), np.array(r["touch"])
            q = np.percentile(x[touch], [10, 50, 90])
            print(f"| {name} | {touch.sum()} of {len(x)} | {q[1]:.2f} [{q[0]:.2f}, {q[2]:.2f}] m | "
                  f"{np.mean((x[touch] >= 0.5) & (x[touch] <= 1.0)):.0%} |")


def short(run: str) -> str:
    """A run folder's name in tables: docs/overnight/seed1 -> overnight/seed1."""
    return "/".join(os.path.normpath(run).split(os.sep)[-2:]).replace("docs/", "")


def outcome_shares(xs) -> str:
    """cleared / band / short shares of every episode of a score set (blown-up episodes left out)."""
    o = ballu.episode_outcome("obstacle", [[np.nan if v is None else v for v in row] for row in xs]).ravel()
    o = o[o >= 0]
    return " / ".join(f"{np.mean(o == k):.0%}" for k in (2, 1, 0))


def cmd_rescore_table(a) -> None:
    """Table II's obstacle rows, the head-to-head and the design landscape under the facts' J and the strict J,
    from `rescore`'s JSON; Fig. 8 of each run's obstacle D2 under both rules beside it (--figures DIR)."""
    from report.paper import PAPER_TABLE2
    from runkit.stats import bootstrap_ci, paired_comparison, verdict
    res = json.load(open(a.rescore))
    runs = [r for r in dict.fromkeys(k.split("|")[0] for k in res) if a.only is None or r == a.only]
    if not runs:
        raise SystemExit(f"stay_band rescore-table: --only {a.only!r} is not a run of {a.rescore}")
    get = lambda run, sp, m, rule: res.get(f"{run}|{sp}|{m}|{rule}")   # noqa: E731
    print("Table II, obstacle: mean J [95 % CI] under the facts' rule -> the strict rule (paper); 'baseline "
          "design' = its own policy at the baseline design.\n")
    print("| run | space | baseline design | e2e MLP | e2e MoE | GES | e2e MLP, step-matched |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    def rows(cell):   # a table row per run and space: cell(method, space, facts' set, strict set) per method
        for run in runs:
            for sp in ("d2", "d3"):
                pairs = [(m, [get(run, "d2" if m == "baseline" else sp, m, r) for r in RULES]) for m in METHODS]
                print(f"| {short(run)} | {sp.upper()} | " + " | ".join(
                    "-" if None in fs else cell(m, sp, *fs) for m, fs in pairs) + " |")

    def mean_cell(m, sp, f, s):
        paper = PAPER_TABLE2[("obstacle", sp)].get("design" if m == "baseline" else m)
        ci = "" if m == "baseline" else "[{:.1f}, {:.1f}] ".format(*bootstrap_ci(s["J"]))
        return f"{np.mean(f['J']):.1f} -> **{np.mean(s['J']):.1f}** {ci}" + (f"({paper})" if paper else "")
    rows(mean_cell)
    print("\nWhere the episodes end (facts' walk -> strict walk): cleared / stay band / short, every episode of "
          "every test design.\n")
    print("| run | space | baseline design | e2e MLP | e2e MoE | GES | e2e MLP, step-matched |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    rows(lambda m, sp, f, s: f"{outcome_shares(f['x'])} -> {outcome_shares(s['x'])}")
    print("\nHead-to-head: GES - the other method, mean [95 % paired-bootstrap CI], Wilcoxon p, verdict on "
          "'GES > it': facts' J | strict J.\n")
    print("| run | space | vs e2e MLP | vs e2e MoE | vs e2e MLP, step-matched |")
    print("| --- | --- | --- | --- | --- |")
    for run in runs:
        for sp in ("d2", "d3"):
            cells = []
            for m in ("mlp", "moe", "mlp_matched"):
                parts = []
                for rule in RULES:
                    g, o = get(run, sp, "ges", rule), get(run, sp, m, rule)
                    if g is None or o is None:
                        parts.append("-")
                        continue
                    c = paired_comparison(g["J"], o["J"])
                    parts.append(f"{c['diff']:+.1f} [{c['diff_lo']:+.1f}, {c['diff_hi']:+.1f}], p={c['p']:.2g}, "
                                 f"{verdict(c)}")
                cells.append(" \\| ".join(parts))
            print(f"| {short(run)} | {sp.upper()} | " + " | ".join(cells) + " |")
    print("\nThe design landscape (Fig. 8's data): GES's J over the test designs, SD and best, and the best over "
          "the baseline design's own score: facts' J | strict J.\n")
    print("| run | space | SD | best | best / baseline design |")
    print("| --- | --- | --- | --- | --- |")
    for run in runs:
        for sp in ("d2", "d3"):
            g = [get(run, sp, "ges", r) for r in RULES]
            b = [get(run, "d2", "baseline", r) for r in RULES]
            if None in g or None in b:
                continue
            sd = " \\| ".join(f"{np.std(x['J'], ddof=1):.1f}" for x in g)
            best = " \\| ".join(f"{np.max(x['J']):.1f}" for x in g)
            ratio = " \\| ".join(f"{np.max(x['J']) / y['J'][0]:.1f}x" for x, y in zip(g, b))
            print(f"| {short(run)} | {sp.upper()} | {sd} | {best} | {ratio} |")
    if a.figures:
        from report.figures import fig_sensitivity
        os.makedirs(a.figures, exist_ok=True)
        for run in runs:
            g = [get(run, "d2", "ges", r) for r in RULES]
            if None in g:
                continue
            th = np.array(g[0]["designs"])[:, 2:]
            space = ballu.d2()
            panels = [(f"obstacle, {rule} J", space, th, x["J"], "cm") for rule, x in zip(RULES, g)]
            path = os.path.join(a.figures, f"fig8_{short(run).replace('/', '_')}.png")
            fig_sensitivity(panels, path)
            print(f"\n![Fig. 8 of {short(run)}, facts' J | strict J]({path})")


# ----------------------------------------------------------------------------------------------------------
# 6. Command line
# ----------------------------------------------------------------------------------------------------------
def main(argv=None) -> int:
    p = args.program("python -m experiments.stay_band", __doc__)
    sub = p.add_subparsers(dest="cmd", required=True)
    e = args.command(sub, "ends", "each episode's end in J's walk, per simulator variant", __doc__)
    e.add_argument("runs", nargs="+", help="run folders (their baseline-design policy and obstacle D2 e2e MLP)")
    pr = args.command(sub, "pressed", "scripted pumps into boxes: final pelvis x of robots at the box", __doc__)
    for q in (e, pr):
        q.add_argument("--variants", default=",".join(VARIANTS), help=f"of {', '.join(VARIANTS)}")
        q.add_argument("--out", required=True, help="a JSON file; a rerun goes on where it stopped")
    r = args.command(sub, "rescore", "every obstacle method of committed runs under both rules", __doc__)
    r.add_argument("runs", nargs="+", help="run folders (test_scores.csv, policies/, ges/)")
    r.add_argument("--out", required=True, help="a JSON file; a rerun goes on where it stopped")
    args.add_workers(r)
    pp = args.command(sub, "protocol", "PPO protocol runs' best policies under both rules", __doc__)
    pp.add_argument("folders", nargs="+", help="ppo_protocol --out folders (SETTING/obstacle/seedS/)")
    pp.add_argument("--settings", default="obs_code_vel,strict_train", help="settings (folders) to score")
    pp.add_argument("--milestones", type=int, nargs="+", default=[1_000_000, 2_000_000])
    pp.add_argument("--design", help="score on this one design (single-design runs), e.g. gcr=0.839,spcf=0.017")
    pp.add_argument("--out", required=True, help="a JSON file; a rerun goes on where it stopped")
    args.add_workers(pp)
    pt = args.command(sub, "protocol-table", "J and cleared shares per setting and milestone", __doc__)
    pt.add_argument("protocol", help="protocol's JSON")
    rt = args.command(sub, "rescore-table", "Table II, head-to-head, landscape under both rules", __doc__)
    rt.add_argument("rescore", help="rescore's JSON")
    rt.add_argument("--figures", help="a folder for Fig. 8 under both rules (one PNG per run)")
    rt.add_argument("--only", help="one run's rows, as rescore named it (e.g. docs/overnight/seed1)")
    t = args.command(sub, "table", "the tables of docs/stay_band", __doc__)
    t.add_argument("ends")
    t.add_argument("pressed", nargs="?")
    a = p.parse_args(argv)
    bad = [v for v in getattr(a, "variants", "").split(",") if v and v not in VARIANTS]
    if bad:
        p.error(f"--variants {','.join(bad)}: each one of {', '.join(VARIANTS)}")
    {"ends": cmd_ends, "pressed": cmd_pressed, "rescore": cmd_rescore, "rescore-table": cmd_rescore_table,
     "protocol": cmd_protocol, "protocol-table": cmd_protocol_table, "table": cmd_table}[a.cmd](a)
    return 0


if __name__ == "__main__":
    sys.exit(main())
