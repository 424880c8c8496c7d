"""Vector envs of the project's ids whose faults are clean, named and never hang.

gymnasium's ``AsyncVectorEnv`` and stable-baselines3's ``SubprocVecEnv`` run each env in
a worker process. Their failures, as a user meets them, are not named:

* ``num_envs=0`` is an ``IndexError`` deep in gymnasium;
* two envs whose kwargs shape different spaces (``max_points=8`` beside ``16``) give
  gymnasium's space ``RuntimeError``, with no word of which kwarg differs;
* SB3's worker dies on an exception without sending it: the parent gets a
  ``ConnectionResetError`` (the worker's ``ValueError`` is lost) or, with forked workers
  that hold each other's pipe ends, waits for ever;
* a worker killed mid-run is a ``BrokenPipeError`` at the next step;
* an info entry whose length varies between envs (``landmarks_in_info=True``,
  ``scatterers_in_info=True``: the true landmarks and scatterers in view) cannot be
  stacked by gymnasium: the reset fails and ``close()`` then waits for ever.

This module's helpers do it cleanly:

* :func:`make_vec` (gymnasium): ``num_envs`` checked, the unstackable info flags refused,
  per-env kwargs (``per_env=[{...}, {...}]``) whose spaces differ named (``max_points
  (env 0: 8, env 1: 16)``), workers' errors raised in the parent with their message, a dead
  worker named (:class:`WorkerError`), and ``close()`` that returns (:class:`AsyncVectorEnv`);
* :func:`make_subproc_vec_env` (stable-baselines3): the kwargs validated by making one env
  in the parent first, then :class:`SubprocVecEnv`, whose workers send their exception to the
  parent (re-raised with its type and message, naming the worker) and whose parent notices a
  dead worker instead of waiting on its pipe.

``gym.make_vec`` itself (with ``vectorization_mode="sync"`` or ``"async"``) also refuses the
unstackable info flags when it makes an env of these ids (:func:`check_vector_info_flags`), and
its ``num_envs`` out of range (0, -1, 2.5) is the same ``ValueError`` as :func:`check_num_envs`'s
instead of gymnasium's ``IndexError``: the ids are registered with :class:`SpecKwargs`, whose
``pop("num_envs", n)`` (gymnasium's ``make_vec`` reads the spec's own ``num_envs`` that way before it
builds any env) checks ``n``.

Example:
    >>> import rhs_env
    >>> from rhs_env.vector import make_vec
    >>> make_vec("rhs-highway-v0", num_envs=0)
    Traceback (most recent call last):
    ...
    ValueError: num_envs must be an integer in [1, 256], got 0
"""

from __future__ import annotations

import builtins
import functools
import multiprocessing as mp
import signal
import traceback
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import gymnasium as gym

from rhs_env.num_envs import MAX_ENVS, SpecKwargs, check_num_envs
from rhs_env.registration import UNSTACKABLE_INFO_FLAGS, check_vector_info_flags

__all__ = [
    "MAX_ENVS",
    "UNSTACKABLE_INFO_FLAGS",
    "AsyncVectorEnv",
    "SpecKwargs",
    "WORKER_FAILURE",
    "WorkerError",
    "WorkerPipe",
    "check_num_envs",
    "check_vector_info_flags",
    "differing_kwargs",
    "make_subproc_vec_env",
    "make_vec",
    "raise_worker_failure",
    "send_worker_failure",
    "worker_gone",
]

#: seconds ``close()`` waits for a pending call of a failed vector env before it terminates the workers
CLOSE_TIMEOUT_S = 10.0
#: seconds between the parent's checks that a worker it waits on is still alive
_POLL_S = 0.2
_PIPE_ERRORS = (BrokenPipeError, ConnectionResetError, EOFError, OSError)


class WorkerError(RuntimeError):
    """A vector env's worker failed or is gone; the message names the worker (and its error, when it sent one)."""


def _flatten(d: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(_flatten(v, key + "."))
        else:
            out[key] = v
    return out


def differing_kwargs(kwargs_list: Sequence[Mapping[str, Any]]) -> str:
    """The (dotted) kwargs whose values differ between envs, with each env's value: ``"max_points (env 0: 8, env
    1: 16)"``; ``""`` when all are equal. A key missing from an env counts as ``<default>``."""
    from rhs_env.highway_config import same_value

    flat = [_flatten(k or {}) for k in kwargs_list]
    keys = sorted({k for f in flat for k in f})
    parts = []
    missing = object()
    for key in keys:
        values = [f.get(key, missing) for f in flat]
        if any(not (a is b or (a is not missing and b is not missing and same_value(a, b)))
               for a, b in zip(values, values[1:], strict=False)):
            shown = ", ".join(f"env {i}: {'<default>' if v is missing else repr(v)}" for i, v in enumerate(values))
            parts.append(f"{key} ({shown})")
    return "; ".join(parts)


def _space_mismatch(exc: BaseException, kwargs_list: Sequence[Mapping[str, Any]]) -> ValueError | None:
    """gymnasium's space ``RuntimeError`` as a ``ValueError`` naming the kwargs that differ (None if not that error)."""
    if not isinstance(exc, RuntimeError) or "space" not in str(exc):
        return None
    diff = differing_kwargs(kwargs_list)
    hint = f"the kwargs that differ between the envs: {diff}" if diff else "their kwargs are equal"
    return ValueError(f"the envs of a vector env must have the same observation and action spaces; {hint}. "
                      f"(gymnasium: {str(exc).splitlines()[0]})")


def worker_gone(index: int, process: Any) -> WorkerError:
    """The error for a worker process that is no longer there."""
    code = process.exitcode
    how = "still running but its pipe is closed" if code is None else f"exit code {code}"
    if code is not None and code < 0:
        try:
            how += f", killed by {signal.Signals(-code).name}"
        except ValueError:
            pass
    return WorkerError(f"vector env worker {index} (pid {process.pid}) is gone ({how}); the vector env cannot go "
                       "on: close() it and make a new one")


# --------------------------------------------------------------------------- gymnasium
class AsyncVectorEnv(gym.vector.AsyncVectorEnv):
    """gymnasium's ``AsyncVectorEnv`` whose faults are named and whose ``close()`` returns.

    A dead worker (killed, or exited) is a :class:`WorkerError` naming it and its exit status
    at the next call, instead of a ``BrokenPipeError``; two envs whose spaces differ are a
    ``ValueError`` naming the kwargs that differ (read from each env's spec); ``close()`` after a
    failed call waits at most :data:`CLOSE_TIMEOUT_S` seconds, then terminates the workers.
    The workers' own exceptions reach the parent as gymnasium raises them (type and message).
    """

    def __init__(self, env_fns: Sequence[Callable[[], gym.Env]], **kwargs: Any) -> None:
        if len(env_fns) == 0:
            raise ValueError(f"num_envs must be an integer in [1, {MAX_ENVS}], got 0 (no env functions)")
        try:
            super().__init__(env_fns, **kwargs)
        except RuntimeError as exc:
            if "space" not in str(exc) or not hasattr(self, "processes"):
                raise
            try:
                specs = self.get_attr("spec")
                kwargs_list = [dict(getattr(s, "kwargs", None) or {}) for s in specs]
            except Exception:
                kwargs_list = []
            self.close(terminate=True)
            err = _space_mismatch(exc, kwargs_list)
            raise (err or exc) from None

    def _dead_worker(self) -> WorkerError | None:
        for i, process in enumerate(getattr(self, "processes", [])):
            if not process.is_alive():
                return worker_gone(i, process)
        return None

    def _guard(self, call: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        try:
            return call(*args, **kwargs)
        except _PIPE_ERRORS as exc:
            dead = self._dead_worker()
            if dead is None:
                raise
            raise dead from exc

    def step_async(self, actions: Any) -> None:
        """gymnasium's ``step_async``; a dead worker is a :class:`WorkerError`."""
        self._guard(super().step_async, actions)

    def step_wait(self, timeout: float | int | None = None) -> Any:
        """gymnasium's ``step_wait``; a dead worker is a :class:`WorkerError`."""
        return self._guard(super().step_wait, timeout)

    def reset_async(self, seed: Any = None, options: Any = None) -> None:
        """gymnasium's ``reset_async``; a dead worker is a :class:`WorkerError`."""
        self._guard(super().reset_async, seed=seed, options=options)

    def reset_wait(self, timeout: float | int | None = None) -> Any:
        """gymnasium's ``reset_wait``; a dead worker is a :class:`WorkerError`."""
        return self._guard(super().reset_wait, timeout)

    def call_async(self, name: str, /, *args: Any, **kwargs: Any) -> None:
        """gymnasium's ``call_async``; a dead worker is a :class:`WorkerError`."""
        self._guard(super().call_async, name, *args, **kwargs)

    def call_wait(self, timeout: float | int | None = None) -> Any:
        """gymnasium's ``call_wait``; a dead worker is a :class:`WorkerError`."""
        return self._guard(super().call_wait, timeout)

    def close_extras(self, timeout: float | int | None = None, terminate: bool = False) -> None:
        """gymnasium's ``close_extras`` that returns: a dead worker or a failed pending call terminates the rest."""
        terminate = terminate or self._dead_worker() is not None
        try:
            super().close_extras(timeout=CLOSE_TIMEOUT_S if timeout is None else timeout, terminate=terminate)
        except Exception:
            for process in self.processes:
                if process.is_alive():
                    process.terminate()
            for pipe in self.parent_pipes:
                if pipe is not None:
                    pipe.close()
            for process in self.processes:
                process.join(CLOSE_TIMEOUT_S)


def make_vec(env_id: str, num_envs: int = 1, vectorization_mode: str = "async",
             vector_kwargs: Mapping[str, Any] | None = None, per_env: Sequence[Mapping[str, Any]] | None = None,
             **kwargs: Any) -> gym.vector.VectorEnv:
    """A gymnasium vector env of ``num_envs`` envs ``gym.make(env_id, **kwargs, **per_env[i])``, checked first.

    Args:
        env_id: a registered id (``"rhs-highway-slam-v0"``).
        num_envs: envs, [1, :data:`MAX_ENVS`].
        vectorization_mode: ``"async"`` (:class:`AsyncVectorEnv`, one worker process per env) or ``"sync"``.
        vector_kwargs: kwargs of the vector env class (``{"context": "fork"}``).
        per_env: optional list of ``num_envs`` dicts of kwargs for each env on top of ``kwargs``; when
            their spaces differ, the ``ValueError`` names the kwargs that differ.
        **kwargs: the envs' kwargs (as for ``gym.make``).

    Returns:
        The vector env (``env.close()`` returns even after a failure).

    Raises:
        ValueError: ``num_envs`` out of range, an unknown mode, ``per_env`` of the wrong length,
            an unstackable info flag (:data:`UNSTACKABLE_INFO_FLAGS`), spaces that differ, or a bad
            env kwarg (raised when the first env is made, in this process).
    """
    from rhs_common.validation import check_choice
    from rhs_env.registration import check_env_id

    n = check_num_envs(num_envs)
    check_choice("vectorization_mode", vectorization_mode, ("async", "sync"))
    check_env_id(env_id)
    if per_env is not None and (not isinstance(per_env, Sequence) or len(per_env) != n
                                or not all(isinstance(p, Mapping) for p in per_env)):
        raise ValueError(f"per_env must be a list of {n} dicts of kwargs (one per env), got {per_env!r}")
    kwargs_list = [{**kwargs, **(per_env[i] if per_env else {})} for i in range(n)]
    for kw in kwargs_list:
        check_vector_info_flags(kw, force=True)
    fns = [functools.partial(gym.make, env_id, **kw) for kw in kwargs_list]
    vkw = dict(vector_kwargs or {})
    try:
        if vectorization_mode == "sync":
            return gym.vector.SyncVectorEnv(fns, **vkw)
        return AsyncVectorEnv(fns, **vkw)
    except RuntimeError as exc:
        err = _space_mismatch(exc, kwargs_list)
        if err is None:
            raise
        raise err from None


# --------------------------------------------------------------------------- stable-baselines3
WORKER_FAILURE = "__rhs_vector_worker_error__"


def _worker(remote: Any, parent_remote: Any, env_fn_wrapper: Any, index: int) -> None:  # pragma: no cover - a child
    """stable-baselines3's worker loop (the same commands) that sends its exception to the parent before it exits."""
    from stable_baselines3.common.env_util import is_wrapped

    parent_remote.close()
    try:
        env = env_fn_wrapper.var()
        reset_info: dict[str, Any] | None = {}
        while True:
            try:
                cmd, data = remote.recv()
            except (EOFError, KeyboardInterrupt):
                break
            if cmd == "step":
                observation, reward, terminated, truncated, info = env.step(data)
                done = terminated or truncated
                info["TimeLimit.truncated"] = truncated and not terminated
                if done:
                    info["terminal_observation"] = observation
                    observation, reset_info = env.reset()
                remote.send((observation, reward, done, info, reset_info))
            elif cmd == "reset":
                maybe_options = {"options": data[1]} if data[1] else {}
                observation, reset_info = env.reset(seed=data[0], **maybe_options)
                remote.send((observation, reset_info))
            elif cmd == "render":
                remote.send(env.render())
            elif cmd == "close":
                env.close()
                remote.close()
                break
            elif cmd == "get_spaces":
                remote.send((env.observation_space, env.action_space))
            elif cmd == "env_method":
                remote.send(env.get_wrapper_attr(data[0])(*data[1], **data[2]))
            elif cmd == "get_attr":
                remote.send(env.get_wrapper_attr(data))
            elif cmd == "has_attr":
                try:
                    env.get_wrapper_attr(data)
                    remote.send(True)
                except AttributeError:
                    remote.send(False)
            elif cmd == "set_attr":
                remote.send(setattr(env, data[0], data[1]))  # type: ignore[func-returns-value]
            elif cmd == "is_wrapped":
                remote.send(is_wrapped(env, data))
            else:
                raise NotImplementedError(f"`{cmd}` is not implemented in the worker")
    except KeyboardInterrupt:
        return
    except Exception as exc:
        send_worker_failure(remote, exc)


def send_worker_failure(conn: Any, exc: BaseException) -> None:
    """Send a worker's exception to the parent (type name, message, traceback: :func:`raise_worker_failure`
    raises it there); a pipe already closed is left so."""
    try:
        conn.send((WORKER_FAILURE, type(exc).__name__, str(exc), "".join(traceback.format_exception(exc))))
    except Exception:
        pass


def raise_worker_failure(index: int, message: tuple[Any, ...]) -> None:
    """Raise a worker's exception in the parent: the builtin type it had (else :class:`WorkerError`), its message."""
    _, name, text, tb = message
    cls = getattr(builtins, name, None)
    what = f"in vector env worker {index}: {text}"
    if isinstance(cls, type) and issubclass(cls, Exception) and cls.__init__ is not None:
        try:
            err = cls(what)
        except Exception:
            err = WorkerError(f"{name} {what}")
    else:
        err = WorkerError(f"{name} {what}")
    err.__notes__ = [f"the worker's traceback:\n{tb}"]
    raise err


class WorkerPipe:
    """The parent end of a worker's pipe: raises the worker's exception, and notices a dead worker."""

    def __init__(self, conn: Any, process: Any, index: int) -> None:
        self.conn, self.process, self.index = conn, process, index

    def send(self, message: Any) -> None:
        try:
            self.conn.send(message)
        except _PIPE_ERRORS:
            raise worker_gone(self.index, self.process) from None

    def recv(self) -> Any:
        try:
            while not self.conn.poll(_POLL_S):
                if not self.process.is_alive() and not self.conn.poll(0):
                    raise worker_gone(self.index, self.process)
            message = self.conn.recv()
        except _PIPE_ERRORS:
            raise worker_gone(self.index, self.process) from None
        if isinstance(message, tuple) and len(message) == 4 and message[0] == WORKER_FAILURE:
            raise_worker_failure(self.index, message)
        return message

    def poll(self, timeout: float = 0.0) -> bool:
        return bool(self.conn.poll(timeout))

    def close(self) -> None:
        self.conn.close()


def _make_subproc_class() -> type:
    """:class:`SubprocVecEnv`, built on first use: importing this module does not import stable-baselines3."""
    from stable_baselines3.common.vec_env import SubprocVecEnv as SB3SubprocVecEnv
    from stable_baselines3.common.vec_env.base_vec_env import CloudpickleWrapper, VecEnv

    class SubprocVecEnv(SB3SubprocVecEnv):
        """stable-baselines3's ``SubprocVecEnv`` whose workers' errors reach the parent and whose dead workers are named.

        A worker's exception (a bad action, a bad kwarg) is sent to the parent before the worker exits and
        raised there with its type and message, naming the worker (its traceback in the exception's notes);
        a worker that died (killed) is a :class:`WorkerError` with its exit status at the next call, never a
        wait on its pipe. After such an error the vector env is good only for ``close()``, which returns.
        """

        def __init__(self, env_fns: list[Callable[[], gym.Env]], start_method: str | None = None) -> None:
            self.waiting = False
            self.closed = False
            n_envs = check_num_envs(len(env_fns))
            if start_method is None:
                start_method = "forkserver" if "forkserver" in mp.get_all_start_methods() else "spawn"
            ctx = mp.get_context(start_method)
            pipes = [ctx.Pipe() for _ in range(n_envs)]
            self.processes = []
            remotes = []
            for i, ((remote, work_remote), env_fn) in enumerate(zip(pipes, env_fns, strict=True)):
                process = ctx.Process(target=_worker,  # type: ignore[attr-defined]
                                      args=(work_remote, remote, CloudpickleWrapper(env_fn), i), daemon=True)
                process.start()
                self.processes.append(process)
                work_remote.close()
                remotes.append(WorkerPipe(remote, process, i))
            self.remotes = remotes
            self.work_remotes = [w for _, w in pipes]
            try:
                self.remotes[0].send(("get_spaces", None))
                observation_space, action_space = self.remotes[0].recv()
            except BaseException:
                self.close()
                raise
            VecEnv.__init__(self, n_envs, observation_space, action_space)

        def close(self) -> None:
            """Close every worker that is still there; returns even after a worker failed or died."""
            if self.closed:
                return
            self.closed = True
            for remote in self.remotes:
                try:
                    remote.conn.send(("close", None))
                except _PIPE_ERRORS:
                    pass
            for process in self.processes:
                process.join(CLOSE_TIMEOUT_S)
                if process.is_alive():
                    process.terminate()
                    process.join(CLOSE_TIMEOUT_S)
            for remote in self.remotes:
                remote.close()

    SubprocVecEnv.__module__ = __name__
    SubprocVecEnv.__qualname__ = "SubprocVecEnv"
    return SubprocVecEnv


@functools.cache
def _subproc_class() -> type:
    return _make_subproc_class()


def __getattr__(name: str) -> Any:
    if name == "SubprocVecEnv":  # built on first use: stable-baselines3 (torch) is imported only then
        return _subproc_class()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def make_subproc_vec_env(env_id: str, n_envs: int = 1, seed: int | None = None,
                         env_kwargs: Mapping[str, Any] | None = None, start_method: str | None = None,
                         check: bool = True, **make_vec_env_kwargs: Any) -> Any:
    """stable-baselines3's ``make_vec_env(env_id, n_envs, ...)`` with :class:`SubprocVecEnv`, its kwargs checked first.

    Args:
        env_id: a registered id; one of this package's ids is given to the workers as ``"rhs_env:<id>"``
            (a forkserver or spawn worker imports ``rhs_env`` first, which registers it).
        n_envs: envs, [1, :data:`MAX_ENVS`].
        seed: the first env's seed (SB3: env i gets ``seed + i``).
        env_kwargs: the envs' kwargs.
        start_method: multiprocessing start method (SB3's default: forkserver where available).
        check: make one env with ``env_kwargs`` in this process first, so a bad kwarg is the ``ValueError`` /
            ``TypeError`` naming the field here, before any worker starts (costs one env construction).
        **make_vec_env_kwargs: further arguments of SB3's ``make_vec_env`` (``wrapper_class``, ``monitor_dir``, ...).

    Returns:
        The ``VecEnv``.
    """
    from stable_baselines3.common.env_util import make_vec_env

    from rhs_env.registration import ENV_SPECS, SLAM_ENV_SPECS, check_env_id

    n = check_num_envs(n_envs)
    check_env_id(env_id)
    kwargs = dict(env_kwargs or {})
    if check:
        gym.make(env_id, **kwargs).close()
    ours = {i for i, _ in ENV_SPECS + SLAM_ENV_SPECS}
    worker_id = f"rhs_env:{env_id}" if env_id in ours else env_id
    return make_vec_env(worker_id, n_envs=n, seed=seed, env_kwargs=kwargs, vec_env_cls=_subproc_class(),
                        vec_env_kwargs={"start_method": start_method}, **make_vec_env_kwargs)
