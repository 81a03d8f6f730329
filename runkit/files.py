"""Files a long run writes and reads back: atomic JSON, and a damaged file named in one line or redone."""
from __future__ import annotations

import json
import os
import warnings
from contextlib import contextmanager

from runkit.progress import say


class BadInput(Exception):
    """A problem with the command line or the output folder: reported in one line, exit code 2."""


@contextmanager
def atomic(path: str, mode: str = "w", newline: str | None = None, durable: bool = False):
    """The project's one atomic write: `with atomic(path) as fh:` writes path.tmp<pid>, then os.replace puts it on
    path, so a killed run never leaves half a file (a failed write leaves neither). durable: fsync first (a power
    cut too)."""
    tmp = f"{path}.tmp{os.getpid()}"
    try:
        with open(tmp, mode, newline=newline) as fh:
            yield fh
            if durable:
                fh.flush()
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def write_json(path: str, obj, indent: int | None = 1, durable: bool = False) -> None:
    """JSON written atomically (atomic), its folder made if missing."""
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    with atomic(path, durable=durable) as fh:
        json.dump(obj, fh, indent=indent)


def read_json(path: str):
    with open(path) as fh:
        return json.load(fh)


class Damaged(BadInput):
    """A file an earlier attempt of this run wrote cannot be read back (truncated, garbage, another format)."""


FRESH = "rerun with --fresh to start over"
READ_ERRORS = (ValueError, KeyError, TypeError, AttributeError, IndexError, EOFError)   # JSON, UTF-8, torch, shape


def read_back(path: str, load=read_json, what: str = "JSON file", fix: str = FRESH):
    """load(path) of a file an earlier attempt wrote; if it is truncated, garbage or of another format, Damaged
    names the file and what to do (a JSON or torch traceback says neither; torch's would even suggest
    weights_only=False on a file we cannot trust)."""
    try:
        with warnings.catch_warnings():   # torch.load warns on foreign pickles: noise beside our one line
            warnings.simplefilter("ignore")
            return load(path)
    except READ_ERRORS as e:
        raise Damaged(f"{path} is damaged (not a readable {what}: {type(e).__name__}); {fix}") from None


def redo_if_damaged(path: str, load=read_json, what: str = "JSON file", part: str = "redoing its part"):
    """read_back of a file whose part the run can redo exactly (every number derives from --seed): a damaged one
    is moved aside to <path>.damaged with a warning and None returned, as for a missing file."""
    if not os.path.exists(path):
        return None
    try:
        return read_back(path, load, what)
    except Damaged as e:
        os.replace(path, path + ".damaged")
        say(f"warning: {str(e).split(';')[0]}: moved aside to {os.path.basename(path)}.damaged; {part}")
        return None
