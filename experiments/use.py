"""experiments/use.py -- use what a run trained: watch a policy or GES on any design, score it on any designs.

    python run_all.py watch docs/overnight/seed0 ges obstacle-d2 --design optimum --level 30 --out anim.gif
    python run_all.py watch docs/overnight/seed0 ges obstacle-d2 --vs mlp --design optimum
    python run_all.py score docs/quick mlp ramp-d3 --design gcr=0.8,spcf=0.01 --design baseline
    python run_all.py score docs/quick/policies/mlp-obstacle-d2/policy.pt obstacle-d2 --design-file d.csv

Contents:
  1. designs: `design_arg` ("gcr=0.86,spcf=0.008", "optimum", "baseline"; experiments/args.py, the rule of every
     command line), `designs_file` (a CSV with a header of names), `level_arg` (--level, or --height in cm / deg)
  2. policies, one rule: `resolve` (RUN METHOD CELL, or CHECKPOINT CELL, or GES-RUN-FOLDER CELL); `play`, the policy
     a design is played by (GES: the density router, paper eq. 10)
  3. `score`: J per design as the run scores it (policies.score_policy), each episode's level and final x
  4. watch: one episode filmed (report/animate.py), alone or beside another method's
  5. the command line

A run decides how it is scored (episodes, start level, episode length, which checkpoint: the preset its manifest
names) and its GES is the cell's main run (run_all.Run.main_ges, the one Table II scores). Deterministic:
ballu.score's episodes start from reset seed 0, and so does a film. Bad input: one line, exit code 2.
"""
from __future__ import annotations

import argparse
import csv
import os
import sys
import time
from dataclasses import dataclass, fields, replace

import numpy as np

import ballu
import ges
import ppo
from codesign import policies
import run_all
from experiments.args import DESIGN_HELP, BadArg, Design, add_workers, command, design_arg, positive, program
from report import animate
from report.figures import level_of
from runkit.files import BadInput, read_json

# ----------------------------------------------------------------------------------------------------------
# 1. Designs and levels
# ----------------------------------------------------------------------------------------------------------
METHODS = {"ges": "GES", "mlp": "e2e MLP", "moe": "e2e MoE", "mlp_matched": "e2e MLP (step-matched)",
           "baseline": "baseline design's policy"}
UseError = BadArg   # bad input: one line naming the value and what is allowed (experiments/args.py)


def designs_file(path: str, space) -> list:
    """Designs from a CSV: a header of parameter names (and optionally `label`), a design a row (design_arg)."""
    if not os.path.isfile(path):
        raise UseError(f"--design-file {path}: no such file")
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    if not rows:
        raise UseError(f"--design-file {path}: no designs (a header such as {','.join(space.names)}, a design a row)")
    out = []
    for i, row in enumerate(rows):
        label = (row.pop("label", "") or "").strip()
        try:
            out.append(design_arg(",".join(f"{k}={v}" for k, v in row.items()), space))
        except UseError as e:
            raise UseError(f"--design-file {path} line {i + 2}: {e}") from None
        out[-1].label = label or out[-1].label
    return out


def start_level(task: str, preset) -> int:
    """The level J starts from: the task's [facts], or the preset's (smoke)."""
    return ballu.SCORE_START_LEVEL[task] if preset.score_start_level is None else preset.score_start_level


def level_arg(level, height, task: str, preset) -> int:
    """--level (0..74) or --height in cm / deg -> the nearest level (report.figures.level_of); default J's start."""
    ends = ballu.level_score(task, [0, ballu.MAX_LEVEL])
    if height is not None:
        if not ends[0] - 0.5 <= height <= ends[1] + 0.5:
            raise UseError(f"--height {height:g}: allowed range [{ends[0]:.1f}, {ends[1]:.1f}] {run_all.UNIT[task]}")
        return level_of(task, height)
    if level is not None and not 0 <= level <= ballu.MAX_LEVEL:
        raise UseError(f"--level {level}: allowed range [0, {ballu.MAX_LEVEL}]")
    return start_level(task, preset) if level is None else level


# ----------------------------------------------------------------------------------------------------------
# 2. Policies: RUN METHOD CELL, or CHECKPOINT CELL, or GES-RUN-FOLDER CELL
# ----------------------------------------------------------------------------------------------------------
@dataclass
class Target:
    """What plays a cell: a single policy (ppo.PolicyFn) or a GES run (ges.GESResult), scored by `preset`."""
    method: str
    task: str
    sp: str
    space: object
    preset: object
    where: str   # the run folder or the path given
    policy: object = None
    ges: object = None


RUN_FILES = ("manifest.json", "results.json")   # a run_all folder's manifest: a live run's, a committed one's


def run_above(path: str) -> str | None:
    """The run folder holding a checkpoint (policies/<name>/x.pt) or a GES run (ges/<name>/[ckpt/x]), if any."""
    up = [os.path.abspath(path)]
    for _ in range(4):
        up.append(os.path.dirname(up[-1]))
    return next((d for d in up[1:] if any(os.path.isfile(os.path.join(d, f)) for f in RUN_FILES)), None)


def run_of(folder: str, workers: int = 2):
    """run_all.Run of an output folder: the preset its manifest names (manifest.json of a live run, results.json's
    of a committed one) with the budgets it recorded (run_all.recorded_preset)."""
    path = next((os.path.join(folder, f) for f in RUN_FILES if os.path.isfile(os.path.join(folder, f))), None)
    if path is None:
        raise UseError(f"{folder}: not a run_all output folder (no manifest.json or results.json)")
    man = read_json(path)
    man = man.get("manifest", man)
    if man.get("preset") not in run_all.PRESETS:
        raise UseError(f"{path}: unknown preset {man.get('preset')!r} (known: {', '.join(run_all.PRESETS)})")
    return run_all.Run(folder, run_all.recorded_preset(man), int(man.get("seed", 0)), workers)


def load_ges(run_dir: str, preset) -> ges.GESResult:
    """A GES run's final territories and specialists: policies.load_ges (state.json) in a run's own folder; in a
    committed one, history.json's last entry (the same mu, sigma and checkpoints; each specialist's last
    checkpoint kept beside it, without ckpt/)."""
    if os.path.isfile(os.path.join(run_dir, ges.STATE_FILE)):
        return policies.load_ges(run_dir)
    if not os.path.isfile(os.path.join(run_dir, ges.HISTORY_FILE)):
        raise UseError(f"{run_dir}: no GES run there (no {ges.STATE_FILE} or {ges.HISTORY_FILE}); a run folder "
                       f"takes RUN METHOD CELL")
    h = read_json(os.path.join(run_dir, ges.HISTORY_FILE))
    last, known = h["rounds"][-1], {f.name for f in fields(ges.GESConfig)}
    ckpt = [os.path.join(run_dir, c if os.path.exists(ppo.scored_path(os.path.join(run_dir, c), preset.policy_rule))
                         else os.path.basename(c)) for c in last["ckpt"]]
    config = ges.GESConfig(**{k: v for k, v in h["config"].items() if k in known})
    return ges.GESResult(
        space=ges.Box.from_dict(h["space"]), config=config, seed=h["seed"], run_dir=run_dir,
        mu_unit=np.array(last["mu_unit"]), sigma_unit=np.array(last["sigma_unit"]), mu=np.array(last["mu"]),
        sigma=np.array(last["sigma"]), ckpt=ckpt, history=h, rounds=last["round"], coverage=last["coverage"],
        ids=last.get("ids", list(range(len(ckpt)))))


def check_fits(policy, task: str, what: str):
    """The policy, if it observed what this task's env gives (ballu.policy_config); else a one-line error."""
    def fits(t):
        try:
            return ballu.policy_config(policy, t) is not None
        except ValueError:
            return False
    if not fits(task):
        other = [t for t in ballu.TASKS if t != task and fits(t)]
        raise UseError(f"{what} is a policy of the {other[0]} task (its observation), not {task}" if other else
                       f"{what} observed another observation set than {task}'s envs give")
    return policy


def resolve(words: list, method: str | None = None, workers: int = 2) -> Target:
    """RUN METHOD CELL: that run's policy (its scored checkpoint, policies.load_policy) or main GES run. CHECKPOINT
    CELL or GES-RUN-FOLDER CELL: that one, scored by the preset of the run folder it lies in, else quick's (the
    facts' J: 20 episodes from the task's start level) [ours]. `method` replaces the words' (--vs)."""
    cells = [f"{t}-{s}" for t in run_all.TASKS for s in run_all.SPACES]
    if len(words) not in (2, 3) or words[-1] not in cells:
        raise UseError(f"cell {words[-1]!r}: one of {', '.join(cells)}" if len(words) in (2, 3) else
                       f"give RUN METHOD CELL or CHECKPOINT CELL, not {' '.join(words)!r}")
    (task, sp), where = words[-1].split("-"), words[0]
    if len(words) == 2:
        up = run_above(where)
        preset = run_of(up).preset if up else run_all.QUICK
        t = Target("ges" if os.path.isdir(where) else "checkpoint", task, sp, policies.space_of(preset, task, sp),
                   preset, where)
        if os.path.isdir(where):
            return replace(t, ges=load_ges(where, preset))
        try:
            return replace(t, policy=check_fits(ppo.load_policy(where), task, where))
        except (ValueError, FileNotFoundError) as e:   # ppo.load_checkpoint's one line
            raise UseError(str(e)) from None
    run, method = run_of(where, workers), method or words[1]
    if method not in METHODS:
        raise UseError(f"method {method!r}: one of {', '.join(METHODS)}")
    t = Target(method, task, sp, policies.space_of(run.preset, task, sp), run.preset, where)
    if method == "ges":
        return replace(t, ges=load_ges(run.path("ges", run.main_ges(task, sp)), run.preset))
    name = f"baseline-{task}" if method == "baseline" else f"{method}-{task}-{sp}"
    if not os.path.exists(ppo.scored_path(policies.policy_ckpt(run, name), run.preset.policy_rule)):
        raise UseError(f"{where}: no {method} policy for {task}-{sp} (policies/{name}/ has no checkpoint)")
    return replace(t, policy=check_fits(policies.load_policy(run, method, task, sp), task, f"policies/{name}"))


def route(res, theta) -> tuple:
    """Paper eq. 10 (ges.route_unit): the specialist of highest Gaussian density at theta, and each one's log density
    (unit cube). Not GESResult.route, which refuses designs outside the box, as the baseline is."""
    x = res.space.to_unit(np.atleast_2d(np.asarray(theta, float)))
    return int(ges.route_unit(x, res.mu_unit, res.sigma_unit)[0]), ges.log_density(x, res.mu_unit, res.sigma_unit)[0]


def play(t: Target, design: Design) -> tuple:
    """(policy, what it is) for one design: the single policy, or the specialist the router picks."""
    if t.ges is None:
        return t.policy, METHODS.get(t.method, t.where)
    k, logd = route(t.ges, design.theta)
    pol = check_fits(policies.load_ges_ckpt(t.ges.ckpt[k], t.preset), t.task, t.ges.ckpt[k])
    return pol, f"GES: specialist {t.ges.ids[k]} of {len(logd)} (log density {logd[k]:.2f})"


# ----------------------------------------------------------------------------------------------------------
# 3. score: J per design, as the run scores (policies.score_policy: its episodes, start level, episode length)
# ----------------------------------------------------------------------------------------------------------
def walk(task: str, start: int, xs: list, strict: bool = False) -> tuple:
    """Each episode's level, replayed from the final x's by the curriculum's rule (ballu.curriculum_update, the
    facts' or the strict one; x None, a blow-up, holds the level), and the level after the last: ballu.score
    returns only the final x. The caller checks the last level against J (a blow-up at a finite x, past the speed
    limit, would differ)."""
    levels = [start]
    for x in xs:
        levels.append(levels[-1] if x is None else int(ballu.curriculum_update(task, levels[-1], x, strict=strict)))
    return levels[:-1], levels[-1]


OUTCOME_MARK = {-1: "-", 0: "s", 1: "b", 2: "C"}   # blown up, short, stay band, cleared (ballu.OUTCOMES)


def outcomes(task: str, xs: list) -> np.ndarray:
    """Each episode's end as ballu.episode_outcome reads it (-1 for a blow-up, x None)."""
    return ballu.episode_outcome(task, [np.nan if x is None else x for x in xs])


def score(t: Target, designs: list, episodes: int | None = None, workers: int = 2, label: str = "",
          rule: str | None = None) -> list:
    """A row per design: J as Table II scores (the preset's episodes unless `episodes`; its rule unless `rule`,
    "facts" or "strict"), each episode's level, final x and outcome; for GES the routed specialist and its log
    density, each specialist's designs in one call (as ges.RoutedEvaluator)."""
    preset = t.preset if episodes is None else replace(t.preset, score_episodes=episodes)
    preset = preset if rule is None else replace(preset, score_strict=rule == "strict")
    rows, groups = [{"design": d} for d in designs], {}
    for i, d in enumerate(designs):
        if t.ges is not None:
            k, logd = route(t.ges, d.theta)
            rows[i].update(specialist=t.ges.ids[k], log_density=float(logd[k]), k=k)
        groups.setdefault(rows[i].get("k"), []).append(i)
    for k, idx in groups.items():
        pol = t.policy if k is None else check_fits(policies.load_ges_ckpt(t.ges.ckpt[k], preset), t.task, t.ges.ckpt[k])
        full, trace = np.array([designs[i].full for i in idx]), {}
        j = policies.score_policy(pol, full, t.task, preset, workers, label + ("" if k is None else f" specialist {k}"),
                                 trace=trace)
        for i, jj, f in zip(idx, j, full):
            xs = trace[f.tobytes()]
            levels, last = walk(t.task, start_level(t.task, preset), xs, preset.score_rule(t.task))
            rows[i].update(J=float(jj), x=xs, levels=levels, outcome=outcomes(t.task, xs),
                           walk_ok=bool(np.isclose(ballu.level_score(t.task, last), jj)))
    return rows


def cmd_score(a) -> None:
    t = resolve(a.policy, workers=a.workers)
    designs = [design_arg(s, t.space) for s in a.design or ([] if a.design_file else ["optimum"])]
    designs += designs_file(a.design_file, t.space) if a.design_file else []
    if a.rule == "strict" and t.task != "obstacle":
        raise UseError(f"--rule strict: the obstacle's rule (its stay band is a robot at the box); {t.task} has "
                       f"the facts' rule only")
    rule = a.rule or ("strict" if t.preset.score_rule(t.task) else "facts")
    print(f"scoring {METHODS.get(t.method, t.where)} ({t.where}, {t.task} {t.sp}) on {len(designs)} design(s): "
          f"{a.episodes or t.preset.score_episodes} episodes from level {start_level(t.task, t.preset)} "
          f"({t.preset.name} preset's J, the {rule} rule), {a.workers} worker(s)", flush=True)
    t0, rows, unit = time.time(), score(t, designs, a.episodes, a.workers, t.method, rule), run_all.UNIT[t.task]
    out, n = a.out or f"scores-{t.method}-{t.task}-{t.sp}.csv", max(len(r["x"]) for r in rows)
    with open(out, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["design", *ballu.DESIGN_NAMES, f"J_{unit}", "rule", "cleared", "band", "short", "specialist",
                    "log_density"] + [f"level_{e + 1}" for e in range(n)] + [f"x_{e + 1}" for e in range(n)])
        for r in rows:
            d, gs, o = r["design"], "specialist" in r, r["outcome"]
            w.writerow([d.label, *[f"{v:.6g}" for v in d.full], f"{r['J']:.4g}", rule,
                        *[int((o == k).sum()) for k in (2, 1, 0)], r.get("specialist", ""),
                        f"{r['log_density']:.4f}" if gs else ""] + r["levels"]
                       + ["" if x is None else f"{x:.4f}" for x in r["x"]])
            print(f"{d.label:>24}  {'  '.join(f'{name} {v:.4g}' for name, v in zip(t.space.names, d.theta))}  J "
                  f"{r['J']:5.1f} {unit}" + (f"  specialist {r['specialist']} (log density {r['log_density']:.2f})"
                                             if gs else ""))
            print(f"{'levels':>30}  {' '.join(f'{v:>4}' for v in r['levels'])}"
                  + ("" if r["walk_ok"] else "  (replayed walk != J: a blown-up episode)"))
            print(f"{'final x, m':>30}  {' '.join('   -' if x is None else f'{x:4.2f}' for x in r['x'])}")
            print(f"{'outcome':>30}  {' '.join(f'{OUTCOME_MARK[int(k)]:>4}' for k in o)}  cleared "
                  f"{(o == 2).sum()} of {len(o)}, stay band {(o == 1).sum()}, short {(o == 0).sum()}")
    print(f"wrote {out} ({len(rows)} designs, {time.time() - t0:.0f} s); outcome: C cleared (past x = "
          f"{ballu.task_geometry(t.task)['up']} m), b stay band, s short, - blown up")


# ----------------------------------------------------------------------------------------------------------
# 4. watch: one episode filmed, alone or beside another method's (report/animate.py)
# ----------------------------------------------------------------------------------------------------------
def design_text(d: Design) -> str:
    """'optimum: gcr 0.88  spcf 0.008  legs 0.45 m' (the label only when it is a name)."""
    legs = f"{d.full[0]:.3g}" if d.full[0] == d.full[1] else f"{d.full[0]:.3g}/{d.full[1]:.3g}"
    return ("" if "=" in d.label else f"{d.label}: ") + f"gcr {d.full[2]:.3g}  spcf {d.full[3]:.3g}  legs {legs} m"


def cmd_watch(a) -> None:
    if a.vs and len(a.policy) != 3:
        raise UseError("--vs needs the RUN METHOD CELL form (a method of the same run)")
    targets = [resolve(a.policy, workers=1)] + ([resolve(a.policy, a.vs, 1)] if a.vs else [])
    t0, t = time.time(), targets[0]
    design, level = design_arg(a.design, t.space), level_arg(a.level, a.height, t.task, t.preset)
    out = a.out or f"watch-{t.method}{'-vs-' + a.vs if a.vs else ''}-{t.task}-{t.sp}-L{level}.gif"
    try:
        animate.check_writer(out)
    except RuntimeError as e:   # MP4 without ffmpeg
        raise UseError(str(e)) from None
    films = []
    for tg in targets:
        pol, what = play(tg, design)
        print(f"filming {what} on {design.label} at {animate.level_text(t.task, level)} ...", flush=True)
        cfg = tg.preset.env_config(ballu.policy_config(pol, tg.task))   # as policies.score_policy plays it
        f = animate.film(pol, tg.task, design.full, level, cfg, a.every, a.max_steps, a.size)
        print(f"  {len(f['frames'])} frames, {animate.outcome(tg.task, f['final_x'], f['blowup'])[0]}", flush=True)
        films.append((f, [what, design_text(design)]))
    frames = animate.panel_frames(films, t.task, level, int(animate.HOLD_S * a.fps))
    animate.save_animation(out, frames, a.fps)
    print(f"wrote {out}: {len(frames)} frames, {os.path.getsize(out) / 1e6:.2f} MB, {time.time() - t0:.0f} s")


# ----------------------------------------------------------------------------------------------------------
# 5. The command line
# ----------------------------------------------------------------------------------------------------------
WORDS_HELP = (f"RUN METHOD CELL (a run_all output folder; METHOD: {', '.join(METHODS)}; CELL: obstacle-d2 ... "
              "ramp-d3), or CHECKPOINT CELL, or GES-RUN-FOLDER CELL")


def picture(text: str) -> tuple:
    w, _, h = text.lower().partition("x")
    if not (w.isdigit() and h.isdigit() and 16 <= int(w) <= 2000 and 16 <= int(h) <= 2000):
        raise argparse.ArgumentTypeError(f"{text!r} is not WxH with 16..2000 pixels each (e.g. 320x240)")
    return int(w), int(h)


def parser() -> argparse.ArgumentParser:
    p = program("python run_all.py", __doc__, "Watch or score a trained policy or GES run on any design.")
    sub = p.add_subparsers(dest="cmd", required=True)
    w = command(sub, "watch", "film one episode as a GIF (or MP4)", __doc__)
    s = command(sub, "score", "J per design, each episode's level and final x, a CSV", __doc__)
    for q, what in ((w, "watch-<method>[-vs-<method>]-<cell>-L<level>.gif"), (s, "scores-<method>-<cell>.csv")):
        q.add_argument("policy", nargs="+", metavar="WORDS", help=WORDS_HELP)
        q.add_argument("--out", help=f"output file (default: {what} in this folder)")
    w.add_argument("--design", default="optimum", help=f"of the cell's space: {DESIGN_HELP}; default optimum")
    w.add_argument("--vs", metavar="METHOD", help="a second method of the same run, side by side")
    lv = w.add_mutually_exclusive_group()
    lv.add_argument("--level", type=int, help="curriculum level 0..74 (default: J's start level)")
    lv.add_argument("--height", type=float, help="obstacle height in cm or ramp angle in deg (nearest level)")
    w.add_argument("--every", type=positive, default=4, help="a frame every N control steps (20 Hz); default 4")
    w.add_argument("--fps", type=positive, default=10, help="frames per second of the file; default 10 (2x real time)")
    w.add_argument("--size", type=picture, default=(animate.WIDTH, animate.HEIGHT), help="each panel's picture, WxH")
    w.add_argument("--max-steps", type=positive, help="stop the episode after N control steps (a quick look, tests)")
    s.add_argument("--design", action="append", help=f"of the cell's space: {DESIGN_HELP}; repeatable; default optimum")
    s.add_argument("--design-file", metavar="CSV", help="a CSV of designs: a header of names (and label), a row each")
    s.add_argument("--episodes", type=positive, help="episodes of J (default: the run's preset's score_episodes)")
    s.add_argument("--rule", choices=("facts", "strict"), help="J's curriculum rule: the facts' (an episode in the "
                   "stay band keeps its level) or strict (obstacle: down unless it cleared); default: the run's")
    add_workers(s, "worker processes scoring the designs", positive)
    w.set_defaults(run=cmd_watch)
    s.set_defaults(run=cmd_score)
    return p


def main(argv=None) -> int:
    """Exit code 0; 2 with one line on bad input (a design outside the space, a missing file, an unknown method
    or cell, a checkpoint of another task or observation set)."""
    a = parser().parse_args(argv)
    try:
        a.run(a)
    except BadInput as e:
        print(f"run_all.py: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
