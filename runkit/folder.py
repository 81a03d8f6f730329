"""A run's output folder: refuse one that holds another run, start over or reuse it, and name the code."""
from __future__ import annotations

import hashlib
import os
import shutil
import subprocess

from runkit.files import FRESH, BadInput, read_back, read_json, write_json
from runkit.plan import CALIBRATION_FILE


def git_commit(where: str) -> str:
    """The short commit of the checkout at `where`, '+dirty' if tracked files changed, 'unknown' without git."""
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=where, capture_output=True, text=True,
                             timeout=10)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=where,
                               capture_output=True, text=True, timeout=10).stdout.strip()
        return out.stdout.strip() + ("+dirty" if dirty else "") if out.returncode == 0 else "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def code_hash(where: str, files, version: int) -> str:
    """Hash of the code that produces a run's numbers, `files` under `where` in this order, plus its results format
    `version`: a results folder made by other code is refused instead of mixed (check_output)."""
    h = hashlib.sha256(str(version).encode())
    for name in files:
        with open(os.path.join(where, name), "rb") as fh:
            h.update(fh.read())
    return h.hexdigest()[:16]


def check_ours(out: str) -> bool:
    """True if `out` holds a run (its manifest.json); False if it is missing, empty or holds only a calibration
    (`--plan` measured this machine there before the run); refuses a file and a folder of somebody else's."""
    if os.path.exists(out) and not os.path.isdir(out):
        raise BadInput(f"--out {out} exists and is not a folder")
    if not (os.path.isdir(out) and set(os.listdir(out)) - {CALIBRATION_FILE}):
        return False
    if not os.path.exists(os.path.join(out, "manifest.json")):
        raise BadInput(f"{out} is not empty and has no manifest.json: not a run_all.py folder; choose another --out")
    return True


def check_output(out: str, manifest: dict, fresh: bool, defaults: dict | None = None) -> bool:
    """Read-only check of the output folder; True if it holds this very run (reuse its finished work).
    Refuses a non-empty folder that is not ours, and one made by another preset / budgets / seed / code
    version unless --fresh. A budget the folder's older code did not have ran as its `defaults` value."""
    mpath = os.path.join(out, "manifest.json")
    if not check_ours(out):
        return False
    if fresh:   # ours (it has a manifest.json), wiped whatever that file holds
        return False
    old = read_back(mpath, lambda p: dict(read_json(p)), fix=f"{FRESH} or choose another --out")
    keys = ("results_format", "preset", "seed", "code_hash")
    diff = [f"{k} ({old.get(k)!r} there, {manifest[k]!r} now)" for k in keys if old.get(k) != manifest[k]]
    was, now = {**(defaults or {}), **(old.get("budgets") or {})}, manifest["budgets"]
    diff += [f"budget {k} ({was[k]!r} there, {now[k]!r} now)" for k in now if k in was and was[k] != now[k]]
    if diff:
        raise BadInput(f"{out} holds results of a different " + ", ".join(diff)
                       + "; rerun with --fresh to start over or choose another --out")
    return not fresh


def open_output(out: str, manifest: dict, reuse: bool) -> dict:
    """Start over (wipe our own old folder) or reuse it; returns the folder's manifest. A folder with only a
    calibration keeps it: the run goes on at the rates its --plan gave."""
    mpath = os.path.join(out, "manifest.json")
    if reuse:
        return read_json(mpath)
    try:
        if os.path.exists(mpath):
            shutil.rmtree(out)   # check_output allowed it: ours and --fresh
        os.makedirs(out, exist_ok=True)
        write_json(mpath, manifest)
    except OSError as e:
        shutil.rmtree(out, ignore_errors=True)   # a failed command leaves no empty folder behind
        raise BadInput(f"cannot write to output folder {out}: {e}") from None
    return manifest
