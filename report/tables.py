"""The tables and claims of REPORT.md: each cell "ours (paper)", each claim a verdict from paired tests."""
from __future__ import annotations

import csv
import math
import os
import zlib

import numpy as np

import ballu
from ges import GESConfig, log_f
from report.paper import (CELLS, METHOD_NAMES, PAPER_COST, PAPER_KSENS_PEAK_K, PAPER_PEAK, PAPER_PEAK_DESIGN,
                          PAPER_TABLE1, PAPER_TABLE2, PAPER_TABLE3, PAPER_TPE_TRIALS, PAPER_WINS)
from runkit.plan import rates_of, rates_source
from runkit.stats import CI_LEVEL, N_BOOT, bootstrap_ci, paired_comparison, verdict

# [ours] the gait features Fig. 5's claim is measured by, in the report's words
GAIT_FEATURES = {"peak_toe_cm": "peak toe height, cm", "step_hz": "step frequency, Hz",
                 "airborne_pct": "time with both toes up, %"}


def mean_ci(x, seed: int = 0, fmt: str = "{:.1f}") -> str:
    """'mean [95 % CI]' over test designs."""
    lo, hi = bootstrap_ci(x, seed)
    return f"{fmt.format(float(np.mean(x)))} [{fmt.format(lo)}, {fmt.format(hi)}]"


def cell_ci(scores, paper, seed: int = 0) -> str:
    """'ours [95 % CI] (paper)'."""
    return f"{mean_ci(scores, seed)} ({'-' if paper is None else f'{paper:.1f}'})"


def comparison_cell(cmp: dict, paper_win=None) -> str:
    """A paired comparison as one table cell: difference [CI], p-value; win rate [CI] (paper's win rate)."""
    pw = "-" if paper_win is None else f"{paper_win:.0f}"
    return (f"{cmp['diff']:+.1f} [{cmp['diff_lo']:+.1f}, {cmp['diff_hi']:+.1f}], p={cmp['p']:.2g}; "
            f"wins {cmp['win_pct']:.0f} % [{cmp['win_lo']:.0f}, {cmp['win_hi']:.0f}] ({pw}), ties {cmp['tie_pct']:.0f} %")


def cell(ours, paper, fmt="{:.1f}", paper_fmt=None) -> str:
    """'ours (paper)'; a missing number is '-'. paper_fmt: the paper's own precision if it differs."""
    o = "-" if ours is None else fmt.format(ours)
    p = "-" if paper is None else (paper_fmt or fmt).format(paper)
    return f"{o} ({p})"


def md_table(header: list, rows: list) -> list:
    """A markdown table as lines: the header, its rule, one line per row, and a blank line."""
    line = lambda values: "| " + " | ".join(str(v) for v in values) + " |"   # noqa: E731
    return [line(header), "|" + "---|" * len(header)] + [line(r) for r in rows] + [""]


def report_header(p, seed: int, commit: str, manifest: dict) -> list:
    """REPORT.md's title and the run's settings: seed, code, and every budget of preset `p` in words."""
    bcfg = ballu.BalluConfig()
    return [f"# ballu-ges: the paper's tables and figures, regenerated (preset `{p.name}`)", "",
            "Every cell is **ours (paper)**. Paper numbers are constants in report/paper.py quoted from "
            "the paper's tables and text; ours are only what this run measured (PyBullet BALLU, our PPO/GES/TPE, "
            "the budgets below). '-' = not measured yet / not given by the paper.", "",
            f"- seed {seed}; git commit {commit} (results folder created at {manifest['git_commit']}); "
            f"code hash {manifest['code_hash']}",
            f"- MDP: the policies observe `obs={bcfg.obs!r}` ("
            + "; ".join(f"{t}: {', '.join(ballu.obs_blocks(ballu.BalluConfig(task=t)))}" for t in ballu.TASKS)
            + f") and are rewarded by `reward_form={bcfg.reward_form!r}` (ballu.BalluConfig; "
            "docs/facts.md, Sec. 8)",
            f"- budgets: {p.ppo_steps:,} PPO control steps per policy ({p.ppo_envs} envs x {p.ppo_rollout} steps "
            f"per update, initial mean action {p.ppo_init_action_mean}, training lanes start "
            + {"task": "at uniform levels up to the score's start level on the ramp, at level 0 on the obstacle "
                       "(ours, the PPO protocol)",
               "spread": "at uniform levels up to the score's start level (ours, the PPO protocol)",
               "zero": "at level 0"}[p.ppo_start] + "); GES "
            + (f"{p.ges_first_round_steps:,} steps per specialist in round 0 (facts: the authors' first round is "
               "3.2x the later ones), then " if p.ges_first_round_steps is not None else "")
            + f"{p.ges_round_steps:,} steps per specialist per round, <= {p.ges_max_rounds} rounds, "
            + ("then one more round on the final territories (ours, docs/ges_schedule), " if p.ges_final_train else "")
            + ("probe ties broken by the mean final x (ours), " if p.probe_tiebreak else "")
            + ("specialists start from their cell's e2e MLP (ours, to fit the budget; paper: random init), "
               if p.ges_warm_start else "") +
            f"F = {p.ges_probes} probes of {p.ges_probe_pool}, {p.ges_init_designs} seed designs per territory "
            f"(facts: 50{'' if p.ges_init_designs == 50 else '; ours: coverage growth is set by F / n_init'}), "
            f"target coverage {p.ges_target_coverage:.0%}, "
            f"K = {p.K_d2} (D2) / {p.K_d3} (D3); {p.n_test} test designs per task/space; {p.tpe_trials} TPE "
            f"trials ({p.tpe_startup} random first); {score_text(p)}; design setup: {p.setup}"] + (
        ["- overridden from the command line (`--set`): " + ", ".join(
            f"{k}={','.join(map(str, v)) if isinstance(v, list) else v}" for k, v in manifest["overrides"].items())]
        if manifest.get("overrides") else []) + [""]


def score_text(p) -> str:
    """How preset `p` scores, in the report's words (start level and probe schedule when they are ours)."""
    facts = " / ".join(f"{v} ({t})" for t, v in ballu.SCORE_START_LEVEL.items())
    start = f"{p.score_start_level} (ours; facts: {facts})" if p.score_start_level is not None else facts
    probe = (f"; GES probes scored with level steps {list(p.probe_level_steps)} (ours; paper: the 20-episode J)"
             if p.probe_level_steps else "")
    rule = ("obstacle J by the strict rule (ours: an episode that does not end past x = 1.0 m goes down a level; "
            "docs/stay_band)" if p.score_strict else "obstacle J by the facts' rule (an episode ending between "
                                                     "x = 0.5 and 1.0 m keeps its level; strict rule: docs/stay_band)")
    train = "; obstacle training curriculum strict (ours)" if p.train_strict else ""
    return f"episodes per score J: {p.score_episodes} (paper: 20) from level {start}{probe}; {rule}{train}"


def report_wall(times: dict, planned: dict, stages, command: str, rate: tuple, cal: dict | None = None) -> list:
    """Each stage's wall time (`times`, all attempts) beside --plan's at this attempt's workers (`planned`, by
    `command`, at the rates of the run's calibration `cal`, or the constants), in `stages`' order, and the PPO
    rate the run trained at (`rate`: runkit.logs.training_rate) beside the plan's: a stage over its plan while
    the run trained below the plan's rate says the machine slowed after it was measured, not that the plan is
    wrong (docs/presets.md: this machine drifts +-20 % and more)."""
    ratio = lambda s, p: f"{s / p:.2f}" if p else "-"   # noqa: E731
    rows = [[n, f"{times[n]:.0f} s", f"{planned[n]:.0f} s" if n in planned else "-", ratio(times[n], planned.get(n))]
            for n in stages if n in times]
    total = sum(times.values())   # the plan over the same stages, so a run under way compares like with like
    total_plan = sum(v for n, v in planned.items() if n in times)
    rows.append(["total", f"{total:.0f} s = {total / 3600:.2f} h", f"{total_plan:.0f} s = {total_plan / 3600:.2f} h",
                 ratio(total, total_plan)])
    (ppo, logs), (train, score) = rate, rates_of(cal)
    lines = ["## Wall time per stage (all attempts)", "",
             f"Plan: `{command}` (GES at its round cap; at {train:.0f} PPO / {score:.0f} score control steps/s per "
             f"core, {rates_source(cal)})."]
    if logs:
        lines += [f"PPO trained at {ppo:.0f} control steps/s per job in this run ({logs} training logs; harmonic "
                  f"mean of their updates), {100 * ppo / train:.0f} % of the plan's {train:.0f}."]
    return lines + [""] + md_table(["stage", "wall time", "plan", "measured / plan"], rows)


def design_words(preset) -> str:
    """The search spaces of a run in the report's words: its setup's boxes and D2 robots (ballu.SETUPS)."""
    if preset.setup == "table":
        return ("D2 = (gcr, spcf) with l_f = l_t = 0.45 m; D3 = (gcr, spcf, l) with l = l_f = l_t, the symmetric leg "
                "length (paper Sec. III-B); Table I's box.")
    boxes = "; ".join(f"{t}: gcr {b['gcr']}, spcf {b['spcf']}, l {b['l']}, D2 robot (l_f, l_t) = "
                      f"{ballu.AUTHORS_D2_LEGS[t]} m" for t, b in ballu.AUTHORS_BOX.items())
    return ("D2 = (gcr, spcf) on one robot per task; D3 = (gcr, spcf, l) with l = l_f = l_t (paper Sec. III-B); the "
            f"authors' experiments' boxes and robots (facts, docs/facts.md sec. 14): {boxes}.")


def report_table1(table1: dict, preset) -> list:
    rows = []
    for name, (low, high, base) in table1["rows"].items():
        paper_low, paper_high, paper_base = PAPER_TABLE1[name]
        rows.append([name, cell(low, paper_low, "{:g}"), cell(high, paper_high, "{:g}"),
                     cell(base, paper_base, "{:g}")])
    return ["## Table I: design space and baseline design", ""] + md_table(
        ["parameter", "lower", "upper", "baseline"], rows) + [f"Search spaces: {design_words(preset)}", ""]


def cells_of(table2: dict) -> list:
    """The (task, space) cells Table II has, in the paper's order (a run may run some only: run_all Preset.cells)."""
    return [(t, s) for t, s in CELLS if f"{t}-{s}" in table2["cells"]]


def report_table2(table2: dict, preset, matched: dict | None = None) -> list:
    """Table II, its TPE peaks and the head-to-head; with the `matched` stage's result, the step-matched e2e MLP
    as a column of each (ours, not in the paper)."""
    means, cells = [], cells_of(table2)
    for t, s in cells:
        scores, paper = table2["cells"][f"{t}-{s}"], PAPER_TABLE2[(t, s)]
        means.append([t, s.upper(), cell(table2["design"][t], paper["design"])]
                     + [cell_ci(scores[m]["scores"], paper.get(m)) for m in ("baseline", "mlp", "moe", "ges")]
                     + ([cell_ci(matched[f"{t}-{s}"]["scores"], None)] if matched else []))
    peaks = []
    for t, s in cells:
        for m in ("mlp", "moe", "ges"):
            peak = table2["peaks"][f"{t}-{s}-{m}"]
            design = " ".join(f"{k}={v:.4g}" for k, v in peak["peak_design"].items())
            paper_design = PAPER_PEAK_DESIGN[(t, s)] if m == "ges" else None
            long_J = cell(peak["peak_long"], PAPER_PEAK[(t, s)][m]) if "peak_long" in peak else "-"
            peaks.append([t, s.upper(), METHOD_NAMES[m], f"{peak['peak']:.1f}", long_J, design,
                          paper_design or "-"])
    wins_rows = []
    for t, s in cells:
        cmps = ges_comparisons(table2, t, s)
        wins_rows.append([t, s.upper()] + [comparison_cell(cmps[m], PAPER_WINS[(t, s)].get(m))
                                           for m in ("baseline", "mlp", "moe")]
                         + ([comparison_cell(matched_comparison(table2, matched, t, s))] if matched else []))
    mcol = ["e2e MLP, step-matched"] if matched else []
    return ([f"## Table II: mean score J over {preset.n_test} uniform test designs (cm obstacle, deg ramp)", "",
             "Cells: ours [95 % bootstrap CI over the test designs] (paper). The paper gives no uncertainty.", ""]
            + md_table(["task", "space", "baseline design", "baseline policy", "e2e MLP", "e2e MoE", "GES"] + mcol,
                       means)
            + ["'baseline design' = the baseline design's own policy at the baseline design (1 design); "
               "'baseline policy' = that policy on the test designs (not in the paper)."
               + (f" {MATCHED_WORDS}" if matched else ""), "",
               f"### Peaks found by TPE ({preset.tpe_trials} trials maximising each method's J)", "",
               f"Each search maximises the {preset.score_episodes}-episode J; its best design is then scored once "
               f"more with a longer J of {preset.peak_episodes or '-'} episodes from the same start level (ours: the "
               f"{preset.score_episodes}-episode J from level 28 cannot exceed "
               f"{ballu.level_score('obstacle', 28 + preset.score_episodes):.0f} cm, below the paper's 54 cm peaks), "
               "the column compared with the paper's peak.", ""]
            + md_table(["task", "space", "method", f"peak J, {preset.score_episodes} episodes",
                        f"peak J, {preset.peak_episodes or '-'} episodes (paper)", "peak design",
                        "paper's peak design"], peaks)
            + [f"Designs: {design_words(preset)}", ""]
            + ["### Head-to-head: GES against each baseline on the same test designs", "",
               "Cells: mean difference GES - baseline [95 % paired-bootstrap CI], Wilcoxon signed-rank p; % of "
               "designs where GES scores higher [95 % CI] (paper's %), % ties.", ""]
            + md_table(["task", "space", "vs baseline policy", "vs e2e MLP", "vs e2e MoE"]
                       + [f"vs {c}" for c in mcol], wins_rows))


# [ours] the step-matched e2e MLP (run_all's stage `matched`), in the report's words
MATCHED_WORDS = ("'e2e MLP, step-matched' = the e2e MLP trained on from the checkpoint GES's specialists start from, "
                 "for as many steps as one specialist trains (ours, not in the paper: is GES's lead "
                 "specialisation or steps? docs/ges_schedule).")


def matched_comparison(table2: dict, matched: dict, task: str, sp: str) -> dict:
    """GES against the step-matched e2e MLP of one cell, paired over the same test designs."""
    return paired_comparison(table2["cells"][f"{task}-{sp}"]["ges"]["scores"], matched[f"{task}-{sp}"]["scores"],
                             seed=zlib.crc32(f"{task}{sp}matched".encode()))


def report_table3(table3: dict, preset) -> list:
    rows = []
    for init, r in table3.items():
        paper_mean, paper_min, paper_max = PAPER_TABLE3.get(init, (None, None, None))
        rows.append([init, cell_ci(r["scores"], paper_mean), cell(r["min"], paper_min, "{:.1f}", "{:g}"),
                     cell(r["max"], paper_max, "{:.1f}", "{:g}"), r["rounds"], f"{r['coverage']:.1%}"])
    return ([f"## Table III: GES initialisation (K = {preset.K_d2}, obstacle, D2, {preset.n_test} test designs, cm)",
             ""] + md_table(["init", "mean [95 % CI] (paper)", "min", "max", "GES rounds", "final coverage"], rows)
            + cap_note(table3, preset, "init "))


def fixed_K(ksens: dict) -> dict:
    """Fig. 7's fixed-K results, without adaptive K's "auto" entry (run_all's Preset.ksens_auto)."""
    return {k: v for k, v in ksens.items() if k != "auto"}


def report_ksens(ksens: dict, preset=None) -> list:
    best = max(fixed_K(ksens), key=lambda k: ksens[k]["mean"])
    rows = [[f"auto (ends at {r['final_K']})" if K == "auto" else K, mean_ci(r["scores"]), f"{r['std']:.1f}",
             f"{r['min']:.1f}", f"{r['max']:.1f}", r["rounds"], f"{r['coverage']:.1%}"] for K, r in ksens.items()]
    return (["## K sensitivity (Fig. 7; obstacle, D2, cm)", "",
             f"Paper: no numbers, performance peaks at K = {PAPER_KSENS_PEAK_K}. Ours peaks at K = {best}.", ""]
            + md_table(["K", "mean [95 % CI]", "std", "min", "max", "GES rounds", "final coverage"], rows)
            + cap_note(ksens, preset, "K = "))


def report_ges_runs(ges_runs: dict, preset=None) -> list:
    """GES's runs: rounds and final coverage; a run below the target coverage stopped at the preset's round cap,
    and the report says so and why (the paper runs to 95 %)."""
    lines = ["## GES stage 1 runs", ""] + md_table(
        ["run", "rounds", "final coverage"], [[n, r["rounds"], f"{r['coverage']:.1%}"] for n, r in ges_runs.items()])
    return lines + cap_note(ges_runs, preset)


def cap_note(runs: dict, preset, what: str = "") -> list:
    """A line naming the GES runs that stopped below the target coverage, at the preset's round cap, and why."""
    short = [f"{what}{n}" for n, r in runs.items() if preset and r["coverage"] < preset.ges_target_coverage]
    if not short:
        return []
    return [f"Below {preset.ges_target_coverage:.0%} coverage: {', '.join(short)}, stopped at the round cap of "
            f"{preset.ges_max_rounds} (the paper's runs go on to {preset.ges_target_coverage:.0%}; the cap bounds the "
            f"{preset.name} preset's wall time, the steps going to the specialists' training instead: "
            "docs/presets.md).", ""]


def report_cost(cost: dict) -> list:
    extrapolated = (f" (per-design BO: {cost['bo_trials_run']} trials measured, extrapolated to {cost['trials']})"
                    if cost["extrapolated"] else "")
    unit = cost.get("unit", "s")   # core-s since the fair layout; older results hold wall seconds
    rows = [["per-design BO", f"{cost['bo_s']:.0f} {unit}", f"{PAPER_COST['bo_h']:.0f} h"],
            ["GES co-design (warm-start e2e MLP + stage 1 + TPE with router)",
             f"{cost['ges_s']:.0f} {unit} ({cost.get('ges_warm_start_s', 0):.0f} + {cost['ges_stage1_s']:.0f} + "
             f"{cost['ges_tpe_s']:.0f})", f"{PAPER_COST['ges_h']:.0f} h (no warm start)"],
            ["reduction", f"{cost['reduction_pct']:.0f} %", f"{PAPER_COST['reduction_pct']:.0f} %"],
            ["best J found: per-design BO / GES", f"{cost['bo_peak']:.1f} / {cost['ges_peak']:.1f}", "-"]]
    if "bo_trial_s" in cost:
        bo = np.asarray(cost["bo_trial_s"], float)
        n, lo, hi = break_even(cost)
        ges_at_paper = cost["ges_fixed_s"] + PAPER_TPE_TRIALS * cost["ges_per_trial_s"]
        at_paper = 1 - ges_at_paper / (PAPER_TPE_TRIALS * bo.mean())
        rows += [["per-design BO, one trial (a PPO training + J)",
                  f"{bo.mean():.0f} {unit} (sd {bo.std(ddof=1) if len(bo) > 1 else 0:.0f}, {len(bo)} trials)", "-"],
                 ["GES: fixed cost / one trial (a routed J)",
                  f"{cost['ges_fixed_s']:.0f} / {cost['ges_per_trial_s']:.0f} {unit}", "-"],
                 ["trials after which GES costs less (break-even)", f"{n:.1f} [{lo:.1f}, {hi:.1f}]", "-"],
                 [f"reduction at the paper's {PAPER_TPE_TRIALS} trials (extrapolated from the per-trial costs)",
                  f"{100 * at_paper:.0f} %", f"{PAPER_COST['reduction_pct']:.0f} %"]]
    layout = (["Ours in core-seconds: every job on one core, as many at once as there are workers, each timed "
               "where it ran, both sides in this one layout; the paper's in wall hours.", ""] if unit == "core-s"
              else [])
    return ([f"## Computational cost ({cost['task']}, {cost['space'].upper()}, {cost['trials']} TPE trials, this "
             f"machine){extrapolated}", ""] + layout + md_table(["", "ours", "paper"], rows))


def report_figures(figures: dict) -> list:
    ent = figures["moe_gate_entropy"]   # None: the run has no obstacle D3 (Fig. 4)
    return (["## Figures", ""] + ([f"MoE gate entropy on the 10 designs of Fig. 4 (normalised, 1 = uniform = "
                                   f"collapse; paper: 'nearly equal weight'): {ent:.2f}; GES: 0 (hard).", ""]
                                  if ent is not None else [])
            + [f"- {k}: [{v}]({v})" for k, v in figures["files"].items()] + [""])


def ges_comparisons(table2: dict, task: str, sp: str) -> dict:
    """GES against each baseline method of one Table II cell, paired over the same test designs."""
    c = table2["cells"][f"{task}-{sp}"]
    return {m: paired_comparison(c["ges"]["scores"], c[m]["scores"], seed=zlib.crc32(f"{task}{sp}{m}".encode()))
            for m in ("baseline", "mlp", "moe")}


def best_of(results: dict, claimed: str) -> str:
    """The claim 'setting `claimed` scores highest' from paired comparisons on the same test designs:
    supported if it beats every other (p < 0.05), not supported if any other beats it, else not resolved."""
    if claimed not in results:
        return "not measured"
    cmps = [paired_comparison(results[claimed]["scores"], r["scores"], seed=i) for i, (k, r) in
            enumerate(results.items()) if k != claimed]
    verdicts = [verdict(c) for c in cmps]
    if verdicts and all(v == "supported" for v in verdicts):
        return "supported"
    return "not supported" if "not supported" in verdicts else "not resolved"


def gait_verdict(gaits: dict, alpha: float = 0.05) -> str:
    """Supported if some gait feature differs between specialists at p < alpha / features (Bonferroni)."""
    ps = [f["p"] for f in gaits["features"].values()]
    return "supported" if min(ps) < alpha / len(ps) else "not resolved"


def gait_evidence(gaits: dict) -> str:
    return "; ".join(f"{GAIT_FEATURES[k]} " + "/".join(f"{m:.1f}" for m in f["mean"]) + f" (p={f['p']:.2g})"
                     for k, f in gaits["features"].items()) + (f"; {gaits['K']} specialists x {gaits['designs']} "
                                                                  "designs, Friedman")


def designs_needed(results: dict, claimed: str, power_z: float = 2.8) -> str:
    """How many test designs a paired test would need to resolve each comparison the run left open, at the
    measured spread of the paired differences: n = (2.8 sd / |mean|)^2 (two-sided 5 %, 80 % power)."""
    if claimed not in results:
        return f"no run of {claimed}"
    need = []
    for k, r in results.items():
        if k == claimed:
            continue
        d = np.asarray(results[claimed]["scores"], float) - np.asarray(r["scores"], float)
        if verdict(paired_comparison(results[claimed]["scores"], r["scores"])) == "not resolved":
            need.append(math.inf if d.mean() == 0 else (power_z * d.std(ddof=1) / abs(d.mean())) ** 2)
    if not need:
        return "every comparison resolved"
    n = max(need)
    return "a verdict needs " + ("more designs than any budget (mean difference 0)" if math.isinf(n)
                                 else f"~{math.ceil(n)} test designs at the measured spread")


def break_even(cost: dict, seed: int = 0) -> tuple:
    """Trials after which GES co-design (a fixed cost: warm start + stage 1; then a cheap routed J per trial)
    costs less than per-design BO (a PPO training per trial): n* = fixed / (BO per trial - GES per trial), with a
    bootstrap interval over the measured BO trials. inf where BO's trial is not dearer."""
    bo = np.asarray(cost["bo_trial_s"], float)
    fixed, per = cost["ges_fixed_s"], cost["ges_per_trial_s"]
    n_star = lambda b: fixed / (b - per) if b > per else math.inf   # noqa: E731
    boots = np.random.default_rng(seed).choice(bo, (N_BOOT, len(bo))).mean(axis=1)
    lo, hi = np.quantile([n_star(b) for b in boots], ((1 - CI_LEVEL) / 2, (1 + CI_LEVEL) / 2),
                         method="inverted_cdf")   # no interpolation: n* may be inf
    return n_star(bo.mean()), float(lo), float(hi)


def cost_claim(cost: dict) -> list:
    """The cost claim from the break-even trial count: supported if even its interval's upper end, with the
    machine's drift on top, lies below the paper's 40 trials; not supported if its lower end lies above."""
    n, lo, hi = break_even(cost)
    paper = PAPER_TPE_TRIALS
    v = ("supported" if hi * (1 + COST_DRIFT_PCT / 100) < paper else
         "not supported" if lo / (1 + COST_DRIFT_PCT / 100) > paper else "not resolved")
    return [f"GES co-design costs less compute than per-design BO at the paper's {paper} trials", v,
            f"break-even after {n:.1f} trials [{lo:.1f}, {hi:.1f}] (BO {len(cost['bo_trial_s'])} trials measured; "
            f"+-{COST_DRIFT_PCT:.0f} % drift allowed)"]


COST_DRIFT_PCT = 20.0   # [ours] this machine's speed drifts +-20 % between runs (developers' guide, measured)


def claim_rows(results: dict) -> list:
    """Each paper claim this run measures, as [claim, verdict, evidence], from this run's numbers only (paired
    tests, p < 0.05); `results` maps stage names to their results (REPORT.md's and report.cross_seed's rows)."""
    rows = []
    t2 = results.get("table2")
    if t2:
        for m, name in (("mlp", "e2e MLP"), ("moe", "e2e MoE")):
            for t, s in cells_of(t2):
                cmp = ges_comparisons(t2, t, s)[m]
                rows.append([f"GES > {name}, {t} {s.upper()}", verdict(cmp),
                             f"{cmp['diff']:+.1f} [{cmp['diff_lo']:+.1f}, {cmp['diff_hi']:+.1f}], p={cmp['p']:.2g}"])
    if t2 and results.get("matched"):
        for t, s in cells_of(t2):
            cmp = matched_comparison(t2, results["matched"], t, s)
            rows.append([f"GES > the e2e MLP at a specialist's steps, {t} {s.upper()} (ours)", verdict(cmp),
                         f"{cmp['diff']:+.1f} [{cmp['diff_lo']:+.1f}, {cmp['diff_hi']:+.1f}], p={cmp['p']:.2g}"])
    fig = results.get("figures")
    if fig and fig.get("moe_gate_entropy") is not None:
        ent = fig["moe_gate_entropy"]
        rows.append(["the e2e MoE's gate is near uniform (normalised entropy >= 0.9 on Fig. 4's designs, ours)",
                     "supported" if ent >= 0.9 else "not supported", f"entropy {ent:.2f}"])
    gaits = (fig or {}).get("specialist_gaits")
    if gaits:
        rows.append(["specialists behave differently (Fig. 5; obstacle D2, ours: gait features)",
                     gait_verdict(gaits), gait_evidence(gaits)])
    else:
        rows.append(["specialists behave differently (Fig. 5)", "not resolved", "no number; see Fig. 5"])
    if results.get("table3"):
        rows.append(["FPS + Lloyd is the best initialisation", best_of(results["table3"], "fps+lloyd"),
                     "paired against every other init; " + designs_needed(results["table3"], "fps+lloyd")])
    if results.get("ksens"):
        ks = fixed_K(results["ksens"])
        rows.append([f"K = {PAPER_KSENS_PEAK_K} is the best K", best_of(ks, str(PAPER_KSENS_PEAK_K)),
                     "paired against every other K; " + designs_needed(ks, str(PAPER_KSENS_PEAK_K))])
    cost = results.get("cost")
    if cost and "bo_trial_s" in cost:
        rows.append(cost_claim(cost))
    elif cost:
        red = cost["reduction_pct"]   # one timing per side, no CI: only a saving beyond the machine's drift counts
        rows.append(["GES co-design costs less compute than per-design BO",
                     "supported" if red > COST_DRIFT_PCT else "not supported" if red < -COST_DRIFT_PCT
                     else "not resolved", f"reduction {red:.0f} % (one measurement each, no CI; beyond "
                     f"+-{COST_DRIFT_PCT:.0f} % counts)"])
    return rows


def report_claims(results: dict) -> list:
    """Which of the paper's claims this run supports: claim_rows under REPORT.md's heading."""
    return (["## Which of the paper's claims does this run support?", "",
             "From this run's numbers only: 'supported' = the claimed difference holds at p < 0.05 (Wilcoxon "
             "signed-rank, paired over the same test designs), 'not supported' = the opposite holds at p < 0.05, "
             "'not resolved' = neither.", ""] + md_table(["claim", "verdict", "evidence"], claim_rows(results)))


# --- where GES meets the e2e MLP: the specialists' own designs and the rest -----------------------------------
def ges_of(stages: dict, t: str, s: str) -> dict | None:
    """The Table II GES run of a cell (stage ges's run named '<task>-<space>-K...'), None if there is none."""
    return next((g for name, g in (stages.get("ges") or {}).items() if name.startswith(f"{t}-{s}-")), None)


def territory_split(stages: dict, folder: str) -> dict:
    """Per Table II cell, [inside, outside]: the test designs inside GES's final territories (max_k f_k > tau,
    eq. 8: the designs coverage counts), where a specialist plays designs of its own territory, and those
    outside, which the router hands to a specialist trained elsewhere. Each part is (GES - e2e MLP, n, GES J,
    e2e MLP J), means over its designs (None, 0, None, None) if it has none; {} without the folder's
    test_scores.csv (the run's raw Table II)."""
    path = os.path.join(folder, "test_scores.csv")
    if not (stages.get("table2") and os.path.exists(path)):
        return {}
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    out = {}
    for t, s in CELLS:
        g, mine = ges_of(stages, t, s), [r for r in rows if (r["task"], r["space"]) == (t, s)]
        if g is None or not mine:
            continue
        cols = [{"l": "l_f"}.get(n, n) for n in g["names"]]   # D3's symmetric leg l is l_f = l_t
        x = np.array([[float(r[c]) for c in cols] for r in mine])
        inside = log_f(x, np.array(g["mu"]), np.array(g["sigma"])).max(axis=1) > math.log(GESConfig.tau)
        ges_j, mlp_j = (np.array([float(r[m]) for r in mine]) for m in ("ges", "mlp"))
        out[f"{t}-{s}"] = [(float((ges_j - mlp_j)[m].mean()), int(m.sum()), float(ges_j[m].mean()),
                            float(mlp_j[m].mean())) if m.any() else (None, 0, None, None) for m in (inside, ~inside)]
    return out


def why_not(part_in: tuple, part_out: tuple, coverage: float) -> str:
    """Why GES > e2e MLP is not supported in a cell, in a line: how the specialists meet the e2e MLP (which
    they start from) on their own designs, and what the designs outside the territories add."""
    (d_in, n_in, g_in, m_in), (d_out, n_out, g_out, m_out) = part_in, part_out
    parts = []
    if n_in:
        parts.append(f"on their own designs ({n_in} of the test designs, inside the territories) the specialists "
                     f"score {g_in:.1f} against the e2e MLP's {m_in:.1f} ({d_in:+.1f})")
    if n_out:
        parts.append(f"outside them ({n_out} of the test designs, {1 - coverage:.0%} of the space uncovered) "
                     f"specialists trained elsewhere score {g_out:.1f} against {m_out:.1f} ({d_out:+.1f})")
    return "; ".join(parts)


def why_lines(stages: dict, split: dict, label: str = "") -> list:
    """'- <label>cell (verdict): why_not(...).' for each cell of `split` where GES > e2e MLP is not supported."""
    out = []
    for t, s in CELLS:
        if f"{t}-{s}" in split:
            v = verdict(ges_comparisons(stages["table2"], t, s)["mlp"])
            if v != "supported":
                out.append(f"- {label}{t} {s.upper()} ({v}): "
                           f"{why_not(*split[f'{t}-{s}'], ges_of(stages, t, s)['coverage'])}.")
    return out


def report_territories(stages: dict, folder: str) -> list:
    """REPORT.md's split of GES against the e2e MLP by GES's final territories, and for each cell where the
    headline is not supported, the line saying why."""
    split = territory_split(stages, folder)
    if not split:
        return []
    fmt = lambda d, n, g, m: "-" if not n else f"{g:.1f} / {m:.1f} ({d:+.1f}, {n})"   # noqa: E731
    rows = [[f"{t} {s.upper()}", verdict(ges_comparisons(stages["table2"], t, s)["mlp"]),
             f"{ges_of(stages, t, s)['coverage']:.1%}"] + [fmt(*p) for p in split[f"{t}-{s}"]]
            for t, s in CELLS if f"{t}-{s}" in split]
    why = why_lines(stages, split)
    return (["### Where GES meets the e2e MLP: the specialists' own designs and the rest", "",
             "Mean J over the test designs inside GES's final territories (max_k f_k > e^-2, the coverage criterion "
             "of eq. 8), each played by a specialist of its own territory, and outside them, handed by the router "
             "to a specialist trained elsewhere: GES / e2e MLP (GES - e2e MLP, designs).", ""]
            + md_table(["cell", "GES > e2e MLP", "coverage", "inside", "outside"], rows)
            + (["Where GES > e2e MLP is not supported, why:", ""] + why + [""] if why else []))

