"""Progress lines with one ETA formula: GES rounds, TPE trials, PPO updates, a stage's jobs and the whole run."""
from __future__ import annotations

import time

LOADED_S = 5.0       # [ours] a unit done this soon after the start (or the previous such unit) was loaded, not run
ETA_PRIOR_S = 60.0   # [ours] the run's pace starts at 1 as if this much had run to plan: a stage of seconds says little
FOUND_DONE = 0.05    # [ours] a stage that ran in under this share of its plan found its work done (a rerun's baselines)


def eta_s(elapsed: float, done: float, left: float, parallel: int = 1) -> float | None:
    """Seconds until `left` more units are done at the pace so far: `elapsed` seconds bought `done` units
    (None before the first). [ours] With `parallel` units running at once, the first to finish means the other
    parallel - 1 are nearly done too, so they count as done (elapsed / done alone would overstate the first
    ETA of a stage on p workers ~p times)."""
    if done <= 0:
        return None
    return elapsed / (done + parallel - 1) * left


def say(msg: str) -> None:
    print(f"[run_all {time.strftime('%H:%M:%S')}] {msg}", flush=True)


class Progress:
    """'label i/n elapsed eta' lines for the units of a long stage, at most one every `every` seconds.
    The leading units a resumed stage loads (each done within LOADED_S) do not count toward the pace: they
    took no work, and counting them promised a resumed stage's training in seconds."""

    def __init__(self, label: str, total: int, every: float = 10.0, parallel: int = 1):
        self.label, self.total, self.every = label, max(total, 1), every
        self.parallel = max(1, min(parallel, self.total))
        self.t0, self.last = time.time(), 0.0
        self.start, self.loaded = self.t0, 0   # the pace counts the units done after self.t0, the first loaded ones

    def __call__(self, done: int, note: str = "", force: bool = False):
        now = time.time()
        if done == self.loaded + 1 and now - self.t0 < LOADED_S:
            self.t0, self.loaded = now, done
        if not force and now - self.last < self.every and done < self.total:
            return
        self.last = now
        eta = eta_s(now - self.t0, done - self.loaded, self.total - done, self.parallel)
        eta = "     -" if eta is None else f"{eta:6.0f}s"
        say(f"  {self.label} {done}/{self.total}  elapsed {now - self.start:6.0f}s  eta {eta}  {note}")


class Throttled:
    """Passes progress text (of ppo.train, ballu.score) through at most once every `every` seconds."""

    def __init__(self, prefix: str, every: float = 30.0):
        self.prefix, self.every, self.last = prefix, every, 0.0

    def __call__(self, text: str):
        if time.time() - self.last >= self.every:
            self.last = time.time()
            say(f"    {self.prefix} {text}")


def run_eta(planned: dict, ran: dict, left: list, spent: dict | None = None) -> str:
    """The whole run's ETA: the planned seconds of the stages `left` at the pace so far (the recorded seconds of
    the stages `ran` per planned second, both with ETA_PRIOR_S of planned time added, so a pace of 1 at the
    start), less the `spent` seconds earlier attempts already put into a stage left (a resumed run).
    Skipped stages count for neither, nor does a stage that found its work done (under FOUND_DONE of its plan:
    experiments.rerun's copied baselines, 2 s of a 1.7 h plan, would set a pace of 0.01)."""
    spent = spent or {}
    ran = {s: t for s, t in ran.items() if t >= FOUND_DONE * planned.get(s, 0.0)}
    done_plan = sum(planned.get(s, 0.0) for s in ran)
    ran_s, done_s = sum(ran.values()) + ETA_PRIOR_S, done_plan + ETA_PRIOR_S
    eta = sum(max(0.0, eta_s(ran_s, done_s, planned.get(s, 0.0)) - spent.get(s, 0.0)) for s in left)
    before = sum(spent.get(s, 0.0) for s in left)
    return (f"whole run: eta {eta:.0f}s ({eta / 3600:.2f} h) for {len(left)} stage(s) left"
            + (f" ({before:.0f}s spent on them already)" if before else "") + ", " +
            (f"--plan's time x {ran_s / done_s:.2f} (the pace so far)" if done_plan > 0 else "--plan's time"))


def round_eta(times: dict, rounds_left: int, first_steps: int | None, round_steps: int) -> str:
    """'eta <= Xs' for a run of rounds (it may stop early), each later round training round_steps: at the pace
    of the rounds of that size so far; before any, the first training round's time scaled by steps ('~': the
    rest of a round does not scale). `times`: seconds per saved round, by its number as str; round 0 is the
    initialisation, round 1 trains first_steps (None: round_steps)."""
    if rounds_left <= 0:
        return "eta 0s"
    same = first_steps in (None, round_steps)
    like = [v for k, v in times.items() if int(k) >= 2 or (k == "1" and same)]
    if like:
        return f"eta <= {eta_s(sum(like), len(like), rounds_left):.0f}s"
    if "1" in times:
        return f"eta <= ~{eta_s(times['1'] * round_steps / first_steps, 1, rounds_left):.0f}s"
    return "eta -"
