"""experiments/args.py -- the experiments' command-line vocabulary: --design (design_arg, full_design) on top of
runkit/args.py's program, commands, --help and --workers (re-exported here), the vocabulary of every command line.

    --design D    a design by named values, `gcr=0.86,spcf=0.008` (names not given: the space's fixed values, else
                  the baseline's; `l` sets both legs), or by name: `baseline` (Table I), `optimum` (Sec. V-C)
    --out PATH    names every output, a folder or a file (no positional outputs)
    --workers N   processes; default every core (os.cpu_count(), as run_all.py)
    --envs N      lanes in all (ppo.PPOConfig.num_envs), split over --workers
    --fresh       delete this command's earlier results and start over (run_all.py)
    --seed S      every random draw derives from it

No library module imports this (a tool built on them): ppo.py and tpe.py take their command lines from
runkit/args.py; ballu.py's and ges.py's run experiments/ballu_bench.py and experiments/ges_demo.py in a child
process (runkit.args.delegate).
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass

import numpy as np

from runkit.args import (WORKERS, add_workers, command, delegate, examples, legacy, parse, positive,  # noqa: F401
                         program)   # the generic vocabulary, re-exported for experiments/
from runkit.files import BadInput


class BadArg(BadInput):
    """Bad input: one line naming the value and what is allowed."""


# ----------------------------------------------------------------------------------------------------------
# --design: named values or a name, on a design space (design_arg) or on its own (full_design)
# ----------------------------------------------------------------------------------------------------------
# ballu is imported where a design is read, not here: ges_demo's and same_results' command lines know no robot
OPTIMUM = {"gcr": 0.88, "spcf": 0.008}   # [paper] Sec. V-C, GES's optimum on the obstacle (D2)
NAMES = ("baseline", "optimum")


def named(text: str) -> dict:
    """The values of a design name: baseline [paper] Table I (gcr 0.70, outside the box), optimum (OPTIMUM)."""
    import ballu
    return dict(zip(ballu.DESIGN_NAMES, ballu.BASELINE.tolist())) if text == "baseline" else dict(OPTIMUM)


def fill() -> dict:
    """The values of the names a design leaves out: the baseline's [ours]; `l` (both legs) its leg length."""
    import ballu
    return dict(zip(ballu.DESIGN_NAMES, ballu.BASELINE.tolist()), l=float(ballu.BASELINE[0]))
DESIGN_HELP = ("name=value,... (e.g. gcr=0.86,spcf=0.008; names not given take the baseline's values, l sets both "
               "legs), or optimum (gcr 0.88, spcf 0.008 [paper]) or baseline (Table I)")


@dataclass
class Design:
    label: str
    theta: np.ndarray   # the space's own coordinates (GES routes them)
    full: np.ndarray    # (l_f, l_t, gcr, spcf): what a lane receives


def named_values(text: str, names) -> dict:
    """'name=value,...' or a design name (NAMES) as {name: value}, names out of ballu.SPACE_NAMES; `names` (the
    space's) only name the allowed ones in the error."""
    import ballu
    text = text.strip()
    given = named(text) if text in NAMES else {}
    for part in [] if text in NAMES else [p for p in text.split(",") if p.strip()] or [""]:
        name, eq, value = (s.strip() for s in part.partition("="))
        try:
            if not eq or name not in ballu.SPACE_NAMES:
                raise ValueError
            given[name] = float(value)
        except ValueError:
            raise BadArg(f"design {text!r}: {part.strip()!r} is not name=value with a name of {tuple(names)} "
                         f"(or a design name: {', '.join(NAMES)})") from None
    return given


def design_arg(text: str, space) -> Design:
    """A design of `space` from 'name=value,...' or a design name (NAMES). Names not given take ballu.BASELINE's values;
    a name the space fixes (D2's legs) is accepted at its value only. The box is enforced except for 'baseline',
    the paper's reference robot (gcr 0.70, below Table I's 0.72), scored as Table II's baseline column scores it."""
    import ballu
    text = text.strip()
    given, rest = named_values(text, space.names), fill()
    theta = np.array([given.get(n, rest[n]) for n in space.names])
    for n, v, lo, hi in zip(space.names, theta, space.lows, space.highs):
        if text != "baseline" and not lo <= v <= hi:
            why = "" if n in given else " (the baseline's, not given)"
            raise BadArg(f"design {text!r}: {n}={v:g}{why} is outside {space.label}: allowed range "
                         f"[{lo:g}, {hi:g}]")
    full = ballu.BASELINE.astype(float) if text == "baseline" else space.full(theta)[0]
    implied = dict(zip(ballu.DESIGN_NAMES, full), l=full[0] if full[0] == full[1] else None)
    for n, v in given.items():
        if n not in space.names and (implied[n] is None or abs(implied[n] - v) > 1e-9):
            there = f"{n} = {implied[n]} there"
            if n in ("l_f", "l_t") and "l" in space.names:
                there = "l_f = l_t = l: give l"
            raise BadArg(f"design {text!r}: {n} is not free in {space.label} (free: "
                         f"{', '.join(space.names)}; {there})")
    return Design(text, theta, full)


def full_design(text: str) -> np.ndarray:
    """(l_f, l_t, gcr, spcf) from design_arg's form without a space, for a command that plays one design of any
    box (ballu.py strip, ppo_ballu, ppo_diagnose, ppo_protocol): names not given take the baseline's values, `l`
    sets both legs; checked only for what the simulator can represent (ballu.check_design). The old form, four
    numbers l_f,l_t,gcr,spcf, is read with a one-line deprecation."""
    import ballu
    parts = text.split(",")
    if len(parts) == 4 and all(_number(p) for p in parts):
        print(f"--design {text}: four numbers are deprecated; use --design "
              f"{','.join(f'{n}={p.strip()}' for n, p in zip(ballu.DESIGN_NAMES, parts))}", file=sys.stderr)
        text = ",".join(f"{n}={p}" for n, p in zip(ballu.DESIGN_NAMES, parts))
    given = named_values(text, ballu.SPACE_NAMES)
    if "l" in given and {"l_f", "l_t"} & set(given):
        raise BadArg(f"design {text!r}: l sets both legs; give l or l_f, l_t")
    legs = {"l_f": given["l"], "l_t": given["l"]} if "l" in given else {}
    full = {**fill(), **legs, **given}
    try:
        return ballu.check_design([full[n] for n in ballu.DESIGN_NAMES], what=f"design {text!r}")[0]
    except ValueError as e:
        raise BadArg(str(e)) from None


def _number(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


def full_design_type(text: str) -> np.ndarray:
    """full_design as an argparse type: a bad design is argparse's one-line error, exit 2."""
    try:
        return full_design(text)
    except BadArg as e:
        raise argparse.ArgumentTypeError(str(e)) from None
