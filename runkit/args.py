"""The command lines' vocabulary: a program with commands, each with an example, and the shared flags. Every
command line of the project takes its --help and --workers from here (experiments/args.py adds --design).

A command line is a program with commands (`python ges.py demo --out DIR`); its --help lists them, each with an
example (the example lines of its module docstring), and run with no argument it prints that help [ours].
`delegate` runs a tool built on a library module as that module's command line, in a child process: a library
module imports no tool built on it (test_library_imports_no_tool). Imports only argparse, os, subprocess, sys."""
from __future__ import annotations

import argparse
import os
import subprocess
import sys

WORKERS = os.cpu_count() or 1   # --workers' default everywhere: every core, as run_all.py [ours]


# ----------------------------------------------------------------------------------------------------------
# Shared flags and help: a program with commands, each with an example
# ----------------------------------------------------------------------------------------------------------
def positive(text: str) -> int:
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer >= 1")
    return int(text)


def add_workers(p, what: str = "worker processes", kind=int) -> None:
    p.add_argument("--workers", type=kind, default=WORKERS, help=f"{what} (default: every core, {WORKERS} here)")


def examples(doc: str, command: str | None = None) -> str:
    """--help's epilog: the docstring's example lines (indented, `python FILE` or `python -m MODULE`), those of
    `command` (the word after the program) if given."""
    lines = [s for s in doc.splitlines() if s.startswith("    python ")]
    return "examples:\n" + "\n".join(s for s in lines if command is None or _command_of(s) == command)


def _command_of(line: str) -> str:
    words = line.split()
    at = 3 if words[1] == "-m" else 2
    return words[at] if len(words) > at else ""


def program(prog: str, doc: str, description: str | None = None) -> argparse.ArgumentParser:
    """A command line whose --help ends with the docstring's examples."""
    return argparse.ArgumentParser(prog=prog, description=description or doc.strip().splitlines()[0],
                                   formatter_class=argparse.RawDescriptionHelpFormatter, epilog=examples(doc))


def command(sub, name: str, what: str, doc: str) -> argparse.ArgumentParser:
    """Command `name` of a program (sub: its add_subparsers()), its --help ending with the examples naming it."""
    return sub.add_parser(name, help=what, description=what.replace("%%", "%"), epilog=examples(doc, name),
                          formatter_class=argparse.RawDescriptionHelpFormatter)   # help, not description, %-formats


def parse(ap: argparse.ArgumentParser, argv=None, old: dict | None = None) -> argparse.Namespace:
    """argv parsed by `ap`. No argument: the help (the commands, each with an example), exit 0 -- a bare command
    starts nothing [ours]. `old`: the flags legacy() rewrites."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv:
        ap.print_help()
        raise SystemExit(0)
    return ap.parse_args(legacy(argv, old or {}, ap.prog))


def legacy(argv: list, old: dict, prog: str) -> list:
    """argv with the first flag of `old` rewritten to the command it became, with one line on stderr naming the
    new form. old: {"--demo": ("demo", True)}: `--demo DIR` is now `demo --out DIR` (True: its value is --out)."""
    for i, a in enumerate(argv):
        flag, eq, value = a.partition("=")
        if flag in old:
            cmd, takes = old[flag]
            if takes and not eq:
                value = argv[i + 1] if i + 1 < len(argv) else ""
            new = [cmd, *(["--out", value] if takes else []), *argv[:i], *argv[i + 1 + (takes and not eq):]]
            print(f"{prog}: {flag} is deprecated: use {prog} {' '.join(new)}", file=sys.stderr)
            return new
    return argv


def delegate(module: str, argv=None, home: str | None = None) -> int:
    """`python -m module argv...` in a child process, its exit code: the command line of a library file (ges.py,
    ballu.py) or of run_all.py (watch, score) whose tool is built on that file and so imports it; an import back
    would close a circle. `home`: the checkout the module lies in (default: this one), put on the child's path."""
    argv = sys.argv[1:] if argv is None else list(argv)
    home = home or os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (home, os.environ.get("PYTHONPATH")) if p))
    return subprocess.call([sys.executable, "-m", module, *argv], env=env)
