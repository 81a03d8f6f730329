"""A stage's wall time, recorded while it runs, so that a killed attempt still counts."""
from __future__ import annotations

import threading
import time

from runkit.files import redo_if_damaged, write_json


def stage_times(path: str) -> dict:
    """stage_seconds.json: every attempt's wall seconds per stage (a damaged file is moved aside, counting anew)."""
    return redo_if_damaged(path, part="counting the stage times from now on") or {}


STAGE_CLOCK_S = 60.0   # a stage killed by SIGKILL loses at most this much of its recorded wall time


class StageClock:
    """Adds a stage's wall time to stage_seconds.json every `every` seconds and once more at close(), so an
    attempt killed by SIGKILL (a session's end), which runs no `finally`, still counts toward the stage's cost
    (docs/archive/paper_obs/overnight/RUN.md). [ours] A daemon thread ticks."""

    def __init__(self, path: str, name: str, every: float = STAGE_CLOCK_S):
        self.path, self.name, self.t0 = path, name, time.time()
        self.base = stage_times(path).get(name, 0.0)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._tick, args=(every,), daemon=True, name=f"clock_{name}")
        self.thread.start()

    def _write(self) -> None:
        times = stage_times(self.path)
        times[self.name] = self.base + time.time() - self.t0
        write_json(self.path, times)

    def _tick(self, every: float) -> None:
        while not self.stop.wait(every):
            self._write()

    def close(self) -> float:
        """Stop ticking, write the final time; returns this attempt's seconds."""
        self.stop.set()
        self.thread.join()
        self._write()
        return time.time() - self.t0
