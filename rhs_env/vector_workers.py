"""The native vector env's envs in worker processes: ``gym.make_vec(..., vectorization_mode="vector_entry_point",
workers=W)``.

One process steps its envs on one core. With ``workers=W`` (opt-in; 1 by default: one core stays one core) the
``N`` envs are split into ``W`` contiguous groups (``numpy.array_split``: 8 envs on 3 workers are 3 + 3 + 2),
and each group is an :class:`rhs_env.vector_native.RhsVectorEnv` of its own in a worker process. A step sends
each worker its envs' actions, then collects their per-env results; the parent keeps the per-env buffers and
merges the infos as with one process, so the results are those of ``N`` single envs with the same seeds (env ``i``
is reset with ``seed + i``; each worker runs the same per-env autoreset). Only the envs' own work runs in
parallel; the parent's batching, the infos' merge and the pipes' pickling stay serial.

Processes, not threads: the compiled kernels hold the GIL and the BLAS limits (threadpoolctl) are process-wide.
Workers start with ``spawn`` by default (no inherited locks or thread pools; each imports the package and loads
the kernel cache, a few seconds). A worker's exception reaches the parent with its type and message, naming the
worker; a dead worker is a :class:`rhs_env.vector.WorkerError` at the next call (:class:`rhs_env.vector.WorkerPipe`).
"""

from __future__ import annotations

import multiprocessing as mp
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from rhs_env.vector import CLOSE_TIMEOUT_S, WorkerPipe, send_worker_failure

__all__ = ["EnvWorkers", "check_workers"]


def check_workers(workers: Any, num_envs: int) -> int:
    """``workers`` as an int in ``[1, num_envs]``; ``ValueError`` naming ``workers`` and the range otherwise."""
    if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or not 1 <= int(workers) <= num_envs:
        raise ValueError(f"workers must be an integer in [1, {num_envs}] (num_envs), got {workers!r}")
    return int(workers)


# --------------------------------------------------------------------------- the worker's side
def _step(group: Any, actions: list[Any]) -> Any:
    group.step_envs(actions)
    return (group._env_obs, group._rewards, group._terminations, group._truncations, group.env_infos,
            group.final_obs, group.final_infos)


#: the worker's commands: ``(group, local indices, per-env values..., common values...)``; the group is a
#: one-process RhsVectorEnv, whose per-env methods answer for the envs it holds
_COMMANDS: dict[str, Callable[..., Any]] = {
    "step": _step,
    "reset": lambda group, local, seeds, options: group.reset_envs(local, seeds, options),
    "call": lambda group, local, name, args, kwargs: group.call_at(local, name, args, kwargs),
    "get_attr": lambda group, local, name: group.get_attr_at(local, name),
    "set_attr": lambda group, local, values, name: group.set_attr_at(local, name, values),
    "is_wrapped": lambda group, local, wrapper: group.is_wrapped_at(local, wrapper),
    "render": lambda group: list(group.render()),
}


def _serve(pipe: Any, env_fns: Sequence[Callable[[], gym.Env]], autoreset_mode: str, group_class: type) -> None:
    """A worker: a ``group_class`` (:class:`rhs_env.vector_native.RhsVectorEnv`) of its envs in this process,
    answering the parent's commands until ``close``."""
    import rhs_env  # noqa: F401  (registers the ids in a spawned process)

    group = None
    try:
        group = group_class(env_fns, autoreset_mode=autoreset_mode, copy=False)
        pipe.send((group.single_observation_space, group.single_action_space, group.metadata, group.render_mode))
        while True:
            cmd, payload = pipe.recv()
            if cmd == "close":
                break
            pipe.send(_COMMANDS[cmd](group, *payload))
    except (KeyboardInterrupt, EOFError):
        pass
    except Exception as exc:
        send_worker_failure(pipe, exc)
    finally:
        if group is not None:
            group.close()
        pipe.close()


# --------------------------------------------------------------------------- the parent's side
class EnvWorkers:
    """``W`` worker processes that hold and step contiguous groups of a vector env's envs (module docstring).

    Args:
        env_fns: one callable per env that makes it (picklable for ``spawn``: ``functools.partial(gym.make, id,
            **kwargs)``).
        workers: processes, [1, ``len(env_fns)``].
        autoreset_mode: the groups' :class:`~gymnasium.vector.AutoresetMode`.
        group_class: the vector env each worker holds its envs in (:class:`rhs_env.vector_native.RhsVectorEnv`,
            which passes itself: this module does not import it), made with ``copy=False`` and one process.
        context: the multiprocessing start method (``"spawn"``, ``"forkserver"``, ``"fork"``).
    """

    def __init__(self, env_fns: Sequence[Callable[[], gym.Env]], workers: int, autoreset_mode: Any,
                 group_class: type, context: str = "spawn") -> None:
        self.num_envs = len(env_fns)
        workers = check_workers(workers, self.num_envs)
        self.groups = [list(map(int, part)) for part in np.array_split(np.arange(self.num_envs), workers)]
        #: env index -> (worker, index in its group)
        self.where = {i: (w, j) for w, group in enumerate(self.groups) for j, i in enumerate(group)}
        ctx: Any = mp.get_context(context)
        self.pipes: list[WorkerPipe] = []
        try:
            for w, group in enumerate(self.groups):
                parent, child = ctx.Pipe()
                process = ctx.Process(target=_serve, args=(child, [env_fns[i] for i in group],
                                                           str(autoreset_mode.value), group_class),
                                      daemon=True, name=f"rhs-vector-worker-{w}")
                process.start()
                child.close()
                self.pipes.append(WorkerPipe(parent, process, w))
            handshakes = [pipe.recv() for pipe in self.pipes]
        except BaseException:
            self.close()
            raise
        self.observation_space, self.action_space, self.metadata, self.render_mode = handshakes[0]
        for w, (obs_space, act_space, _, _) in enumerate(handshakes):
            if obs_space != self.observation_space or act_space != self.action_space:
                self.close()
                raise ValueError(f"the envs of worker {w} have other spaces than those of worker 0; every env of a "
                                 "vector env needs the same spaces")

    def _by_worker(self, indices: Sequence[int]) -> dict[int, list[tuple[int, int]]]:
        """``{worker: [(position in indices, index in its group), ...]}`` for env ``indices``."""
        out: dict[int, list[tuple[int, int]]] = {}
        for k, i in enumerate(indices):
            w, j = self.where[int(i)]
            out.setdefault(w, []).append((k, j))
        return out

    def reset(self, indices: Sequence[int], seeds: Sequence[int | None], options: dict[str, Any] | None) -> list[Any]:
        """Reset envs ``indices`` with ``seeds``; their ``(obs, info)`` in that order."""
        return self._ask(indices, "reset", per_env=(seeds,), common=(options,))

    def step(self, actions: Sequence[Any]) -> list[tuple[Any, ...]]:
        """Step every env with its action; per env ``(obs, reward, terminated, truncated, info, final_obs,
        final_info)`` in env order."""
        for w, group in enumerate(self.groups):
            self.pipes[w].send(("step", ([actions[i] for i in group],)))
        out: list[tuple[Any, ...]] = []
        for w in range(len(self.groups)):
            obs, rew, term, trunc, infos, final_obs, final_infos = self.pipes[w].recv()
            out.extend(zip(obs, rew, term, trunc, infos, final_obs, final_infos, strict=True))
        return out

    def call(self, indices: Sequence[int], name: str, args: tuple = (), kwargs: dict | None = None) -> list[Any]:
        """``name`` of envs ``indices`` called with ``args`` / ``kwargs`` (or read, when not callable)."""
        return self._ask(indices, "call", common=(name, tuple(args), dict(kwargs or {})))

    def get_attr(self, indices: Sequence[int], name: str) -> list[Any]:
        """``name`` of envs ``indices``."""
        return self._ask(indices, "get_attr", common=(name,))

    def set_attr(self, indices: Sequence[int], name: str, values: Sequence[Any]) -> None:
        """Set ``name`` of envs ``indices`` to ``values`` (one each)."""
        self._ask(indices, "set_attr", per_env=(values,), common=(name,), answers=False)

    def is_wrapped(self, indices: Sequence[int], wrapper: type) -> list[bool]:
        """Whether envs ``indices`` are wrapped in ``wrapper``."""
        return self._ask(indices, "is_wrapped", common=(wrapper,))

    def render(self) -> list[Any]:
        """Every env's frame, in env order."""
        for pipe in self.pipes:
            pipe.send(("render", ()))
        return [frame for pipe in self.pipes for frame in pipe.recv()]

    def _ask(self, indices: Sequence[int], cmd: str, per_env: tuple[Sequence[Any], ...] = (), common: tuple = (),
             answers: bool = True) -> list[Any]:
        """Send ``cmd`` to the workers that hold envs ``indices``, each with its envs' local indices, its slice of
        each ``per_env`` sequence (one value per index) and ``common``, all before the first answer; the answers
        (one per env) in the order of ``indices``, or None each when ``answers`` is False."""
        plan = self._by_worker(indices)
        for w, pairs in plan.items():
            sliced = [[values[k] for k, _ in pairs] for values in per_env]
            self.pipes[w].send((cmd, ([j for _, j in pairs], *sliced, *common)))
        out: list[Any] = [None] * len(indices)
        for w, pairs in plan.items():
            answer = self.pipes[w].recv()
            if answers:
                for (k, _), value in zip(pairs, answer, strict=True):
                    out[k] = value
        return out

    def close(self) -> None:
        """Ask every worker to close its envs and exit; terminate those still running after
        :data:`rhs_env.vector.CLOSE_TIMEOUT_S` seconds."""
        for pipe in getattr(self, "pipes", []):
            try:
                pipe.conn.send(("close", ()))
            except Exception:
                pass
        for pipe in getattr(self, "pipes", []):
            pipe.process.join(CLOSE_TIMEOUT_S)
            if pipe.process.is_alive():
                pipe.process.terminate()
                pipe.process.join(CLOSE_TIMEOUT_S)
            pipe.close()
        self.pipes = []
