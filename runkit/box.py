"""The design box, one home for ges.py and ballu.py: an axis-aligned box of named parameters in physical units,
mapped linearly to the unit cube [0, 1]^d that GES works in [paper, Sec. IV-B: "normalized design space"].

What a design means is the caller's business: ges.py sees only names and bounds; ballu.DesignSpace extends the
box with the robot's fixed values (D2 fixes the legs, D3 ties them)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Box:
    """Names, lows and highs of d design parameters; validate, sample, and map to and from the unit cube."""
    names: tuple
    lows: tuple
    highs: tuple

    def __post_init__(self):
        self.names = tuple(str(n) for n in self.names)
        self.lows, self.highs = tuple(map(float, self.lows)), tuple(map(float, self.highs))
        if not (len(self.names) == len(self.lows) == len(self.highs) >= 1):
            raise ValueError(f"names/lows/highs must have the same length >= 1, got {len(self.names)}/"
                             f"{len(self.lows)}/{len(self.highs)}")
        for n, lo, hi in zip(self.names, self.lows, self.highs):
            if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
                raise ValueError(f"bounds of {n} must be finite with low < high, got [{lo}, {hi}]")

    @classmethod
    def of(cls, space) -> "Box":
        """The plain box of any object with names, lows and highs (e.g. a ballu.DesignSpace)."""
        return cls(tuple(space.names), tuple(space.lows), tuple(space.highs))

    @property
    def d(self) -> int:
        return len(self.names)

    @property
    def lo(self) -> np.ndarray:
        return np.array(self.lows)

    @property
    def hi(self) -> np.ndarray:
        return np.array(self.highs)

    def to_unit(self, theta) -> np.ndarray:
        """Physical -> unit cube (linear per axis)."""
        return (np.asarray(theta, dtype=float) - self.lo) / (self.hi - self.lo)

    def from_unit(self, x) -> np.ndarray:
        """Unit cube -> physical."""
        return self.lo + np.asarray(x, dtype=float) * (self.hi - self.lo)

    def from_unit_scale(self, s) -> np.ndarray:
        """Unit-cube lengths (a territory's sigma) -> physical: scaled per axis, not shifted."""
        return np.asarray(s, dtype=float) * (self.hi - self.lo)

    def validate(self, theta) -> np.ndarray:
        """Return theta as an (n, d) float array, or raise ValueError naming the offending parameter."""
        arr = self._rows(theta)
        outside = self._outside(arr)
        for j, n in enumerate(self.names):
            if outside[:, j].any():
                i = int(np.argmax(outside[:, j]))
                raise ValueError(f"{n}={float(arr[i, j])!r} (row {i}) is outside the design space: allowed range "
                                 f"[{self.lows[j]}, {self.highs[j]}]")
        return arr

    def contains(self, theta) -> np.ndarray:
        """(n,) bools: which of the designs lie in the box, under validate's rule, without raising."""
        return ~self._outside(self._rows(theta)).any(axis=1)

    def _rows(self, theta) -> np.ndarray:
        """theta as an (n, d) float array; a wrong shape raises, naming the columns."""
        arr = np.asarray(theta, dtype=float)
        arr = arr[None, :] if arr.ndim == 1 else arr
        if arr.ndim != 2 or arr.shape[1] != self.d:
            raise ValueError(f"theta has shape {np.shape(theta)}, expected (d,) or (n, d) with d={self.d} "
                             f"columns {self.names}")
        return arr

    def _outside(self, arr: np.ndarray) -> np.ndarray:
        """(n, d) bools: entries non-finite or outside [low, high]; the round-off of from_unit(to_unit(.)) is in."""
        tol = 1e-9 * (self.hi - self.lo)
        return ~np.isfinite(arr) | (arr < self.lo - tol) | (arr > self.hi + tol)

    def sample_uniform(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """n uniform designs, physical units."""
        return self.from_unit(rng.random((n, self.d)))

    def to_dict(self) -> dict:
        return {"names": list(self.names), "lows": list(self.lows), "highs": list(self.highs)}

    @classmethod
    def from_dict(cls, d: dict) -> "Box":
        return cls(tuple(d["names"]), tuple(d["lows"]), tuple(d["highs"]))
