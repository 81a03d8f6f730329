"""Where a run's independent jobs run: a Dask cluster (local, or started by hand and sent this checkout's files)
or a local process pool whose workers end with the run that started them."""
from __future__ import annotations

import glob
import multiprocessing as mp
import os
import tempfile
import threading
import time
import zipfile
from concurrent.futures import Executor, Future, ProcessPoolExecutor, ThreadPoolExecutor, as_completed

from runkit.files import BadInput

CONNECT_TIMEOUT_S = 5
_DASK_CLIENTS: dict = {}


def dask_client(scheduler: str | None, workers: int, files=()):
    """A Dask client, made once per process: connected to `scheduler`, or to a local cluster of `workers`
    processes with one thread each (torch keeps one thread per job).

    A cluster started by hand (`dask scheduler`, `dask worker ADDR` anywhere, no PYTHONPATH) gets `files` (.py
    modules and package folders, in import order) from the client (Client.upload_file, to the scheduler too: it
    unpickles the task graph, which names the modules' functions), and so does every worker that joins later.
    An unreachable or malformed address is a one-line BadInput after CONNECT_TIMEOUT_S, not distributed's 30 s
    wait and traceback."""
    key = (scheduler, workers)
    if key not in _DASK_CLIENTS:
        from distributed import Client, LocalCluster
        if scheduler:
            try:
                client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
            except (OSError, ValueError, TypeError) as e:
                raise BadInput(f"--scheduler {scheduler}: no Dask scheduler reachable there ("
                               f"{str(e).splitlines()[0] if str(e) else type(e).__name__}); give the address that "
                               f"`dask scheduler` prints, e.g. tcp://HOST:8786") from None
            for path in files:
                with tempfile.TemporaryDirectory() as tmp:
                    client.upload_file(package_zip(path, tmp) if os.path.isdir(path) else path)
            _DASK_CLIENTS[key] = client
        else:
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
            _DASK_CLIENTS[key] = Client(cluster)
    return _DASK_CLIENTS[key]


def package_zip(package: str, folder: str) -> str:
    """The package folder `package` as folder/NAME.zip: Client.upload_file puts a zip on the workers' sys.path,
    while it would import a lone .py of a package as a top-level module."""
    name = os.path.basename(os.path.normpath(package))
    path = os.path.join(folder, f"{name}.zip")
    with zipfile.ZipFile(path, "w") as z:
        for f in sorted(glob.glob(os.path.join(package, "*.py"))):
            z.write(f, os.path.join(name, os.path.basename(f)))
    return path


def close_dask_clients() -> None:
    for client in _DASK_CLIENTS.values():
        cluster = client.cluster
        client.close()
        if cluster is not None:
            cluster.close()
    _DASK_CLIENTS.clear()


def dask_executor(client):
    """distributed's concurrent.futures executor (pure=False: every submit runs, none is deduplicated). Its
    shutdown gets the standard `cancel_futures` too (there, wait=False cancels)."""
    ex = client.get_executor(pure=False)
    plain = ex.shutdown
    ex.shutdown = lambda wait=True, cancel_futures=False: plain(wait=wait and not cancel_futures)
    return ex


def exit_with_parent(parent_pid: int, every: float = 1.0) -> None:
    """Pool-worker initializer: end this worker when the run that started it is gone. A killed run_all (kill -9,
    a session's end) otherwise leaves its workers to finish their in-flight training or score set, orphaned,
    each on a core for up to an hour. [ours] A daemon thread polls the parent's pid once a second."""
    def watch():
        while os.getppid() == parent_pid:
            time.sleep(every)
        os._exit(1)
    threading.Thread(target=watch, daemon=True, name="exit_with_parent").start()


class SerialExecutor(Executor):
    """Runs each task inline at submit(): for debugging and tests. Same results as any other Executor."""

    def submit(self, fn, /, *args, **kwargs):
        fut = Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # delivered through the future, like a pool would
            fut.set_exception(exc)
        return fut


def executor(kind: str, workers: int, scheduler: str | None = None, files=(), stop_by: float | None = None,
             inline=SerialExecutor) -> Executor:
    """The executor of a run's independent jobs: kind "dask", a Dask cluster's (dask_client: at `scheduler`, or a
    local one of `workers` processes; a cluster started by hand gets `files`); kind "process", a process pool
    (spawn: the parent holds torch threads; its workers end with the run: exit_with_parent), or `inline()` (an
    executor that runs each job in the caller) with 1 worker. With `stop_by`, no job starts after it (GatedExecutor)."""
    if kind == "dask":
        ex = dask_executor(dask_client(scheduler, workers, files))
    elif workers <= 1:
        ex = inline()
    else:
        ex = ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"), initializer=exit_with_parent,
                                 initargs=(os.getpid(),))
    return ex if stop_by is None else GatedExecutor(ex, stop_by)


def side_by_side(jobs: dict, progress, inline: bool = False) -> dict:
    """Long jobs that each submit their own work to one shared executor, run side by side: `jobs` maps a name to
    fn(stop=None), each run in a thread of this process, so while one waits on its last piece of work another's
    takes the idle core [ours]. When one fails, the others get `stop` set (a threading.Event: each ends at its
    next safe point) and the failure is raised. `inline` (an executor that runs work in the calling thread):
    one job after another. `progress(done, name)` after each; returns name -> result, in `jobs`' order."""
    out = {}
    if inline:
        for i, (name, fn) in enumerate(jobs.items()):
            out[name] = fn()
            progress(i + 1, name)
        return out
    stop = threading.Event()
    with ThreadPoolExecutor(len(jobs)) as threads:
        futures = {threads.submit(fn, stop=stop): name for name, fn in jobs.items()}
        try:
            for i, f in enumerate(as_completed(futures)):
                out[futures[f]] = f.result()
                progress(i + 1, futures[f])
        except BaseException:
            stop.set()
            raise
    return {name: out[name] for name in jobs}


class StopBy(Exception):
    """A job that did not start: the run's stop-by time had passed (GatedExecutor)."""


def clock_text(t: float) -> str:
    """Epoch seconds as this machine's local date and time of day, to the minute (a --stop-by time)."""
    return time.strftime("%Y-%m-%d %H:%M", time.localtime(t))


def _gated(stop_by: float, fn, *args, **kwargs):
    if time.time() >= stop_by:
        raise StopBy(f"no job starts after {clock_text(stop_by)}")
    return fn(*args, **kwargs)


class GatedExecutor(Executor):
    """An executor whose jobs start only before `stop_by` (epoch seconds); one that comes later raises StopBy
    instead of running, checked where and when it starts (a job queued behind others checks when its turn comes).
    Jobs under way finish and keep what they wrote, so a run stopped this way and rerun gives an uninterrupted
    run's numbers, where a kill mid-training would not (a PPO training resumed from a checkpoint starts fresh
    episodes). [ours] For machines whose sessions end at a known time."""

    def __init__(self, inner: Executor, stop_by: float):
        self.inner, self.stop_by = inner, stop_by

    def submit(self, fn, /, *args, **kwargs):
        return self.inner.submit(_gated, self.stop_by, fn, *args, **kwargs)

    def shutdown(self, wait=True, *, cancel_futures=False):
        return self.inner.shutdown(wait=wait, cancel_futures=cancel_futures)


def stop_time(text: str, now: float | None = None) -> float:
    """'HH:MM' (this machine's local time) as epoch seconds: its next occurrence, within 24 h."""
    try:
        hh, mm = (int(x) for x in text.split(":"))
        if not (0 <= hh < 24 and 0 <= mm < 60):
            raise ValueError
    except ValueError:
        raise BadInput(f"--stop-by {text!r} must be a time of day HH:MM (00:00-23:59)") from None
    now = time.time() if now is None else now
    day = time.localtime(now)
    t = time.mktime((day.tm_year, day.tm_mon, day.tm_mday, hh, mm, 0, 0, 0, -1))
    return t if t > now else time.mktime((day.tm_year, day.tm_mon, day.tm_mday + 1, hh, mm, 0, 0, 0, -1))
