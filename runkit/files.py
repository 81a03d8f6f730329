"""Files a long run writes and reads back: atomic JSON, and a damaged file named in one line or redone."""
from __future__ import annotations

import json
import os
import warnings

from runkit.progress import say


class BadInput(Exception):
    """A problem with the command line or the output folder: reported in one line, exit code 2."""


def write_json(path: str, obj) -> None:
    """Atomic write (tmp + replace): a killed run never leaves half a file."""
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "w") as fh:
        json.dump(obj, fh, indent=1)
    os.replace(tmp, path)


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
