"""The one reader of a training log: ppo.TrainLog's CSV, as one array per column."""
from __future__ import annotations

import csv

import numpy as np


def read_log(path: str) -> dict:
    """A learning-curve CSV (a header, then rows of numbers) as {column: array}; a row that is short or not
    numbers raises ValueError, so a caller can tell a damaged file from a good one."""
    with open(path, newline="") as fh:
        header, *rows = list(csv.reader(fh))
    if any(len(r) != len(header) for r in rows):
        raise ValueError(f"{path}: a row's length differs from the header's")
    values = np.array([[float(v) for v in r] for r in rows], dtype=float).reshape(len(rows), len(header))
    return dict(zip(header, values.T))
