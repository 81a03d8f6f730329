"""The one way a settings dataclass checks itself: its __post_init__ calls `need` (or `integer`) per field, and a bad
value is a ValueError naming the class, the field, the value as given and what is allowed, in one line:

    GESConfig.K=0 not allowed: an integer >= 1

Used by ges.GESConfig, tpe.TPEConfig, ppo.PPOConfig and run_all.Preset (whose `--set` errors quote it)."""
from __future__ import annotations

import numpy as np


def need(cfg, name: str, ok: bool, allowed: str) -> None:
    """Raise the one-line ValueError unless `ok` (a test of cfg.<name>)."""
    if not ok:
        raise ValueError(f"{type(cfg).__name__}.{name}={getattr(cfg, name)!r} not allowed: {allowed}")


def integer(cfg, name: str, least: int) -> None:
    """cfg.<name> must be an integer >= least (a bool or a float is refused: a truncated count hides a bug)."""
    v = getattr(cfg, name)
    need(cfg, name, isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= least,
         f"an integer >= {least}")
