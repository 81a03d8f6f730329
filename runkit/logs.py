"""The one reader of a training log (ppo.TrainLog's CSV, as one array per column), and what a run reads from it."""
from __future__ import annotations

import csv
import glob
import os

import numpy as np

from runkit.files import atomic, redo_if_damaged


def read_log(path: str) -> dict:
    """A learning-curve CSV (a header, then rows of numbers) as {column: array}; a row that is short or not
    numbers raises ValueError, so a caller can tell a damaged file from a good one."""
    with open(path, newline="") as fh:
        header, *rows = list(csv.reader(fh))
    if any(len(r) != len(header) for r in rows):
        raise ValueError(f"{path}: a row's length differs from the header's")
    values = np.array([[float(v) for v in r] for r in rows], dtype=float).reshape(len(rows), len(header))
    return dict(zip(header, values.T))


def trim_log(csv_path: str, steps: int) -> None:
    """Drop log rows past a checkpoint's step count (written by a run killed after its last checkpoint), so a
    resumed run's learning curve has no duplicated stretch."""
    if redo_if_damaged(csv_path, read_log, "learning-curve CSV", "its curve restarts here") is None:
        return
    with open(csv_path, newline="") as fh:
        rows = list(csv.reader(fh))
    with atomic(csv_path, newline="") as fh:
        csv.writer(fh).writerows(rows[:1] + [r for r in rows[1:] if int(float(r[0])) <= steps])


def train_seconds(log_csv: str) -> float:
    """A policy's training seconds summed over the attempts that made it, from its learning-curve CSV [ours].

    ppo.train's wall_s restarts at each resume, so a stretch ends where wall_s drops; each stretch counts up to
    its last kept row. Updates lost at a kill (past the last checkpoint, dropped by trim_log) do not count: the
    figure is an uninterrupted training's, which the cost comparison needs (a run spanning sessions is killed
    mid-training; timing only the last attempt counted ~0 s for a policy that the kill had left complete)."""
    total, prev = 0.0, 0.0
    for wall in read_log(log_csv)["wall_s"]:
        wall = float(wall)
        if wall < prev:   # a resumed attempt's first update
            total += prev
        prev = wall
    return total + prev


def resume_points(log_csv: str, planned=()) -> list:
    """Control steps each resumed attempt went on from (its checkpoint's): where wall_s starts again, one update
    before that attempt's first row; without those at a `planned` step (the first whole update at or past it: a
    schedule's own continuation). A checkpoint without the lanes' state (an older ppo.train's) starts every lane
    on a fresh episode there, so such a run gives other numbers than an uninterrupted one; with it, a resume is
    exact."""
    log = read_log(log_csv)
    steps, wall = log["steps"].astype(int), log["wall_s"]
    if len(steps) < 2:
        return []
    per_update = int(steps[1] - steps[0])
    points = [int(steps[i]) - per_update for i in range(1, len(steps)) if wall[i] < wall[i - 1]]
    return [p for p in points if not any(m <= p < m + per_update for m in planned)]


def training_rate(folder: str) -> tuple:
    """(control steps/s per training job, training logs read) over every training log below `folder`: the
    harmonic mean of the logs' per-update rates (every update of a policy trains the same batch), i.e. their
    steps over their time. Other CSV files and damaged logs are skipped."""
    rates = []
    for path in glob.glob(os.path.join(folder, "**", "*.csv"), recursive=True):
        try:
            rates.append(read_log(path)["steps_per_s"])
        except (ValueError, KeyError, OSError):   # not a training log, or a damaged one
            continue
    r = np.concatenate(rates) if rates else np.zeros(0)
    r = r[np.isfinite(r) & (r > 0)]
    return (len(r) / np.sum(1.0 / r) if len(r) else float("nan")), len(rates)
