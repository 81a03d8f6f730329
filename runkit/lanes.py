"""runkit/lanes.py -- the lanes of a batched env in worker processes, for any env constructor.

  1. `WorkerPool`: long-lived spawned workers that run top-level fn(state, *args); `InProcess`, the same calls in
     this process; `shared_pool`, one process-wide pool per worker count; `quiet_stdout` for chatty C libraries
  2. `VecEnv`: num_envs lanes split over W workers, worker k holding make(n_k, lane_ids=ids_k, **kw)
  3. scoring lanes in the workers (`score_lanes`): each walks its curriculum levels, replaying known episodes

Knows no robot: the env comes in as a constructor (a picklable top-level class or function, e.g. ballu.BalluEnv),
so a worker imports the env's module when it unpickles it. The batched interface (Gymnasium's vector-env
conventions): reset(seed=, options=) -> (obs, info); step(actions) -> (obs, reward, terminated, truncated, info),
arrays shaped (num_envs, ...), an episode that ends reset in the same step, its row flagged in info["_final_obs"].
"""
from __future__ import annotations

import atexit
import contextlib
import copy
import multiprocessing as mp
import os
import time

import numpy as np


# ----------------------------------------------------------------------------------------------------------
# 1. Worker processes
# ----------------------------------------------------------------------------------------------------------
@contextlib.contextmanager
def quiet_stdout(fds=(1,)):
    """Silence C-level output (file descriptors; 1 = stdout) in a with-block, e.g. a simulator's C code in every
    worker (PyBullet prints "argv[0]=" on stdout at every connect, and a build-time banner on stderr (2) at
    import). C's own buffers are flushed before the descriptors come back. Python exceptions still propagate."""
    import ctypes
    import sys
    sys.stdout.flush()
    sys.stderr.flush()
    saved, devnull = [os.dup(fd) for fd in fds], os.open(os.devnull, os.O_WRONLY)
    for fd in fds:
        os.dup2(devnull, fd)
    os.close(devnull)
    try:
        yield
    finally:
        ctypes.CDLL(None).fflush(None)
        for fd, keep in zip(fds, saved):
            os.dup2(keep, fd)
            os.close(keep)


def _serve(conn):
    """A worker's loop: run fn(state, *args) for each request; `state` is this worker's private dict, alive as
    long as the worker. Exceptions travel back as ('error', traceback)."""
    import traceback
    os.environ.setdefault("OMP_NUM_THREADS", "1")   # before torch loads: the workers share the cores, one each
    state = {}
    try:
        while True:
            msg = conn.recv()
            if msg is None:
                break
            fn, args = msg
            try:
                conn.send(("ok", fn(state, *args)))
            except Exception:
                conn.send(("error", traceback.format_exc()))
    except (EOFError, KeyboardInterrupt):
        pass
    finally:
        for v in state.values():
            if hasattr(v, "close"):
                v.close()


class WorkerPool:
    """`workers` long-lived spawned processes that run top-level functions fn(state, *args) side by side.

    Start-up (a fresh interpreter importing numpy, the simulator and often torch) costs seconds, so a pool is
    made once and reused: VecEnv keeps one per env (each worker's `state` holds its env), and scoring and the
    open-loop tools share one per worker count (`shared_pool`). A worker that dies raises RuntimeError in the
    caller instead of hanging; `name` names the workers in that error.
    """

    def __init__(self, workers: int = 2, timeout: float = 600.0, name: str = "worker"):
        if not isinstance(workers, (int, np.integer)) or workers < 1:
            raise ValueError(f"workers={workers!r} must be an integer >= 1")
        ctx = mp.get_context("spawn")   # no fork: the parent may hold torch threads
        self.timeout, self.name, self.conns, self.procs = timeout, name, [], []
        for _ in range(workers):
            a, b = ctx.Pipe()
            proc = ctx.Process(target=_serve, args=(b,), daemon=True)
            proc.start()
            b.close()
            self.conns.append(a)
            self.procs.append(proc)

    @property
    def workers(self) -> int:
        return len(self.procs)

    def _recv(self, k):
        conn, proc = self.conns[k], self.procs[k]
        t0 = time.monotonic()
        while not conn.poll(0.5):
            if not proc.is_alive():
                raise RuntimeError(f"{self.name} {k} died (exit code {proc.exitcode})")
            if time.monotonic() - t0 > self.timeout:
                raise RuntimeError(f"{self.name} {k} did not answer within {self.timeout} s")
        try:
            status, out = conn.recv()
        except (EOFError, OSError):
            proc.join(timeout=1)
            raise RuntimeError(f"{self.name} {k} died (exit code {proc.exitcode})") from None
        if status == "error":
            raise RuntimeError(f"{self.name} {k} failed:\n{out}")
        return out

    def call(self, fn, args: list) -> list:
        """fn(state_k, *args[k]) in workers k = 0..len(args)-1 at once; their results, in order. `fn` must be a
        top-level function (pickled by name)."""
        if len(args) > len(self.conns):
            raise ValueError(f"call got {len(args)} argument tuples for {len(self.conns)} workers")
        for conn, a in zip(self.conns, args):
            try:
                conn.send((fn, tuple(a)))
            except (BrokenPipeError, OSError):
                pass   # _recv reports the dead worker
        return [self._recv(k) for k in range(len(args))]

    def close(self):
        for conn in self.conns:
            try:
                conn.send(None)
            except (BrokenPipeError, OSError):
                pass
        for proc in self.procs:
            proc.join(timeout=5)
            if proc.is_alive():
                proc.terminate()
        self.conns, self.procs = [], []

    def __del__(self):
        if getattr(self, "procs", None):
            self.close()


class InProcess:
    """A one-worker WorkerPool that is this process: the same fn(state, *args) calls, with the arguments
    copied as a worker would receive them (so a stateful policy, e.g. a gait's phase counter, is not advanced
    in the caller's hands: workers=1 and workers=2 give the same result)."""

    def __init__(self):
        self.state, self.workers = {}, 1

    def call(self, fn, args: list) -> list:
        if len(args) > 1:
            raise ValueError(f"call got {len(args)} argument tuples for 1 worker")
        return [fn(self.state, *copy.deepcopy(a)) for a in args]


def plain_call(state, fn, args):
    """Run a plain top-level function fn(*args) in a worker (its state unused)."""
    return fn(*args)


_SHARED_POOLS: dict = {}


def shared_pool(workers: int) -> WorkerPool:
    """The process-wide pool of `workers` workers for scoring and the open-loop tools, started on first use
    and closed at exit; a dead one is replaced."""
    pool = _SHARED_POOLS.get(workers)
    if pool is None or not all(p.is_alive() for p in pool.procs):
        if pool is not None:
            pool.close()
        pool = _SHARED_POOLS[workers] = WorkerPool(workers)
    return pool


def close_shared_pools():
    for pool in _SHARED_POOLS.values():
        pool.close()
    _SHARED_POOLS.clear()


atexit.register(close_shared_pools)


# ----------------------------------------------------------------------------------------------------------
# 2. VecEnv: the lanes of one env split over worker processes
# ----------------------------------------------------------------------------------------------------------
# what a VecEnv worker does with the env in its state
def _env_open(state, make, num_envs, lane_ids, kw):
    state["env"] = make(num_envs, lane_ids=lane_ids, **kw)


def _env_call(state, method, *args, **kw):
    return getattr(state["env"], method)(*args, **kw)


def _env_get(state, name):
    return getattr(state["env"], name)


def _env_set(state, name, value):
    setattr(state["env"], name, value)


def _env_run(state, fn, args):
    return fn(state["env"], *args)


def check_split(num_envs, workers):
    """A clear error unless `num_envs` lanes can be split over `workers` workers, each with one lane or more."""
    if not isinstance(workers, (int, np.integer)) or workers < 1:
        raise ValueError(f"workers={workers!r} must be an integer >= 1")
    if not isinstance(num_envs, (int, np.integer)) or num_envs < workers:
        raise ValueError(f"num_envs={num_envs!r} must be an integer >= workers={workers}")


def check_actions(actions, n: int, act_dim: int) -> np.ndarray:
    """Actions as a float (n, act_dim) array, or a clear error (wrong shape, NaN or inf)."""
    a = np.asarray(actions, dtype=float)
    if a.shape != (n, act_dim):
        raise ValueError(f"actions must have shape ({n}, {act_dim}), got {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError("actions contain non-finite values (NaN or inf)")
    return a


def merge_infos(infos):
    """The workers' info dicts as one, each entry's rows in lane order."""
    return {k: np.concatenate([np.asarray(i[k]) for i in infos]) for k in infos[0]}


class VecEnv:
    """`num_envs` lanes split over `workers` processes (a WorkerPool whose worker k holds
    make(n_k, lane_ids=ids_k, **kw)), behind the env's batched interface. Lane ids are global, so a lane's random
    generator and trajectory do not depend on the worker count. A subclass names the reset options given per lane
    (`lane_options`: name -> the ndim of one value for every lane) and the attributes read once from the workers'
    envs (`mirror`)."""
    lane_options: dict = {}
    mirror = ("obs_dim", "act_dim")
    worker_name = "worker"

    def __init__(self, make, num_envs: int, workers: int = 2, timeout: float = 600.0, **kw):
        check_split(num_envs, workers)
        self.num_envs = int(num_envs)
        self.splits = np.array_split(np.arange(num_envs), workers)
        self.pool = WorkerPool(workers, timeout, self.worker_name)
        self.pool.call(_env_open, [(make, len(ids), ids, kw) for ids in self.splits])
        for name in self.mirror:   # the same in every worker's env: read from the first
            setattr(self, name, self.pool.call(_env_get, [(name,)])[0])

    @property
    def procs(self):
        return self.pool.procs

    def _each(self, fn, *args) -> list:
        return self.pool.call(fn, [args] * self.pool.workers)

    def each_call(self, method, *args) -> list:
        """env.method(*args) in every worker; their results, in order."""
        return self._each(_env_call, method, *args)

    def each_get(self, name) -> list:
        """Every worker's env's attribute `name`, in order."""
        return self._each(_env_get, name)

    def each_set(self, name, value):
        """Set attribute `name` of every worker's env to `value`."""
        self._each(_env_set, name, value)

    def gather(self, name) -> np.ndarray:
        """The workers' envs' per-lane attribute `name`, concatenated in lane order."""
        return np.concatenate(self.each_get(name))

    def reset(self, seed=None, options=None):
        options = dict(options or {})
        per = []
        for ids in self.splits:
            o = dict(options)
            for key, ndim in self.lane_options.items():
                if o.get(key) is not None and np.ndim(o[key]) > ndim:
                    o[key] = np.asarray(o[key])[ids]
            per.append(("reset", seed, o))
        outs = self.pool.call(_env_call, per)
        return np.concatenate([o[0] for o in outs]), merge_infos([o[1] for o in outs])

    def get_state(self) -> list | None:
        """The workers' env.get_state(), lane by lane in order (None if some worker's is None)."""
        parts = self.each_call("get_state")
        return None if None in parts else [lane for part in parts for lane in part]

    def set_state(self, lanes: list):
        """env.set_state in each worker with its lanes' saved state (any worker count: the state is per lane)."""
        if len(lanes) != self.num_envs:
            raise ValueError(f"saved state holds {len(lanes)} lanes, this env {self.num_envs}")
        self.pool.call(_env_call, [("set_state", [lanes[i] for i in ids]) for ids in self.splits])

    def step(self, actions):
        a = check_actions(actions, self.num_envs, self.act_dim)
        outs = self.pool.call(_env_call, [("step", a[ids]) for ids in self.splits])
        return tuple(np.concatenate([o[j] for o in outs]) for j in range(4)) + (merge_infos([o[4] for o in outs]),)

    @property
    def parts(self) -> list:
        """Lane indices of each worker, in order."""
        return self.splits

    def run(self, fn, args: list) -> list:
        """fn(worker_env, *args[k]) in every worker k at once; their results, in order. `fn` must be a top-level
        function (pickled by name). ppo.train rolls out so: each worker steps its lanes with its own policy copy."""
        if len(args) != self.pool.workers:
            raise ValueError(f"run needs one argument tuple per worker ({self.pool.workers}), got {len(args)}")
        return self.pool.call(_env_run, [(fn, tuple(a)) for a in args])

    def close(self):
        self.pool.close()


# ----------------------------------------------------------------------------------------------------------
# 3. Scoring in the workers: each lane walks the curriculum levels for a fixed number of episodes
# ----------------------------------------------------------------------------------------------------------
# The env protocol: make(n, lane_ids=ids) gives an env whose reset takes options "designs" and "levels", whose
# step's info holds "_final_obs", "final_x", "levels" (the level each lane plays next), "episode_level" and
# "blowup", with `level_step` (levels a finished episode moves, one per lane) and pause(lanes) (stop stepping
# lanes whose result is known). ballu.score is the caller and says why.
def score_lanes(make, policy, designs, workers: int, start: int, steps, reuse: bool = False, progress=None,
                label: str = "score"):
    """One lane per design walks the levels from `start`, episode e moving steps[e] levels: with workers > 1 the
    designs are split over the long-lived `shared_pool`, each worker playing its lanes with its own copy of the
    policy (its `for_lanes(ids)` part if it has one): no round trip per step, no process start-up per call.
    Returns each lane's final level (n,), each episode's final x (n, episodes) and the episodes played."""
    n, episodes = len(designs), len(steps)
    parts = [ids for ids in np.array_split(np.arange(n), min(workers, n)) if len(ids)]
    part = getattr(policy, "for_lanes", None)   # a policy with per-lane settings hands each worker its part
    args = [(make, policy if part is None or len(parts) == 1 else part(ids), designs[ids], ids, start, steps, reuse)
            for ids in parts]
    call = (InProcess() if len(parts) == 1 else shared_pool(len(parts))).call
    try:
        call(score_open, args)
        for until in range(1, episodes + 1):
            outs = call(score_play, [(until,)] * len(parts))
            if progress:
                progress(f"{label}: {until * n}/{episodes * n} episodes")
    except BaseException:
        with contextlib.suppress(Exception):
            call(score_close, [()] * len(parts))
        raise
    call(score_close, [()] * len(parts))
    return (np.concatenate([o[0] for o in outs]), np.concatenate([o[1] for o in outs]),
            int(sum(o[2] for o in outs)))


def score_open(state, make, policy, designs, lane_ids, start, steps, reuse=False):
    """Scoring, step 1 (in a worker, or in this process with a local `state`): a fresh env, one lane per design;
    `steps[e]` = levels episode e moves (ballu.score's `level_steps`); `reuse`: replay known episodes."""
    n, episodes = len(designs), len(steps)
    env = make(n, lane_ids=lane_ids)
    obs, _ = env.reset(seed=0, options={"designs": designs, "levels": np.full(n, start)})
    env.level_step = np.full(n, steps[0])   # each lane's current episode's step; moves on as episodes end
    state["score"] = {"env": env, "policy": policy, "obs": obs, "count": np.zeros(n, dtype=int), "steps": steps,
                      "final": np.full(n, -1), "x": np.full((n, episodes), np.nan),
                      "known": [{} for _ in range(n)] if reuse else None, "episodes_played": 0}


def _replay_known(s, lanes, levels):
    """Lanes whose next level was played before: a deterministic policy on a deterministic simulator repeats
    that episode exactly, and with unit steps the walk's next level depends on the level alone, so the rest of
    the walk is a cycle through known episodes. Fill it in (final x of each episode, the final level): a walk that
    holds its level or swings between two costs 1-2 episodes after it gets there."""
    count, x, final, known, episodes = s["count"], s["x"], s["final"], s["known"], len(s["steps"])
    for i, lv in zip(lanes, levels):
        lv = int(lv)
        if lv not in known[i]:
            continue
        while count[i] < episodes:
            lv_next, x[i, count[i]] = known[i][lv]
            count[i], lv = count[i] + 1, lv_next
        final[i] = lv


def score_play(state, until):
    """Scoring, step 2: play until every lane has finished `until` of its episodes; the level after a lane's
    last episode is its result (-1 until then). Also returns each episode's final pelvis x."""
    s = state["score"]
    env, policy, count, final, x, steps = s["env"], s["policy"], s["count"], s["final"], s["x"], s["steps"]
    episodes, known = len(steps), s["known"]
    while (np.minimum(count, episodes) < until).any():
        if known is None:
            actions = policy(s["obs"])
        else:   # a pure policy acts row by row: only the lanes still playing are asked
            playing = count < episodes
            some = policy(s["obs"][playing])
            actions = np.zeros((len(count), np.shape(some)[1]))
            actions[playing] = some
        s["obs"], _, _, _, info = env.step(actions)
        done = info["_final_obs"] & (count < episodes)
        if done.any():
            ids = np.flatnonzero(done)
            x[ids, count[ids]] = info["final_x"][ids]
            s["episodes_played"] += len(ids)
            if known is not None:   # a blown-up episode is not kept: its level is played again
                for i in ids[~info["blowup"][ids]]:
                    known[i][int(info["episode_level"][i])] = (int(info["levels"][i]), float(info["final_x"][i]))
            count += done
            env.level_step = steps[np.minimum(count, episodes - 1)]   # the next episode's step
            hit = done & (count == episodes)
            final[hit] = info["levels"][hit]
            if known is not None:
                more = ids[count[ids] < episodes]
                _replay_known(s, more, info["levels"][more])
            env.pause(np.flatnonzero(count >= episodes))   # finished lanes: their worlds stop stepping
    return final.copy(), x.copy(), s["episodes_played"]


def score_close(state):
    s = state.pop("score", None)
    if s is not None:
        s["env"].close()
