"""The native vector env of every id: ``gym.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point")``.

:class:`RhsVectorEnv` holds ``N`` envs made in this process with the same kwargs and steps them in one call.
Its results are those of gymnasium's ``SyncVectorEnv`` of ``N`` single envs: env ``i`` is reset with
``seed + i``, autoreset follows gymnasium's :class:`~gymnasium.vector.AutoresetMode` (``NEXT_STEP`` by default,
as ``SyncVectorEnv``; ``SAME_STEP`` and ``DISABLED`` too), infos are merged by gymnasium's ``_add_info``
(each key an array over envs with its ``_key`` mask).

Keyword arguments of ``gym.make_vec`` go to every env (as for ``gym.make``) except the vector env's own:

* ``autoreset_mode`` (an :class:`~gymnasium.vector.AutoresetMode` or its value ``"NextStep"``, ``"SameStep"``,
  ``"Disabled"``);
* ``copy`` (``True``: the returned observations are copies, as ``SyncVectorEnv``).

* ``workers`` (1 by default): processes that step the envs (:mod:`rhs_env.vector_workers`).

What runs where: by default each env's step runs in turn, in this process, on one core (one core stays one
core). The per-env work is one method (:meth:`RhsVectorEnv.step_envs`), the seam where a batched step over envs
plugs in. ``workers=W`` (opt-in) splits the envs into ``W`` groups, each stepped in a worker process of its own
(:class:`rhs_env.vector_workers.EnvWorkers`), with the same results. Threads across envs are not offered: the
compiled kernels (numba, ``rhs_common.jit``) hold the GIL and the wrappers' BLAS limits (threadpoolctl) are
process-wide, so threads would serialise and could leave the user's BLAS limits changed.

stable-baselines3 takes it through :func:`to_sb3` (a ``VecEnv`` adapter; the vector env in ``SAME_STEP`` mode).

Example:
    >>> import gymnasium as gym
    >>> import rhs_env
    >>> envs = gym.make_vec("rhs-highway-v0", num_envs=2, vectorization_mode="vector_entry_point")
    >>> obs, infos = envs.reset(seed=0)
    >>> obs.shape
    (2, 5, 5)
    >>> envs.close()
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from copy import deepcopy
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space, concatenate, create_empty_array, iterate

from rhs_env.registration import check_vector_info_flags

__all__ = ["RhsVectorEnv", "make_vector_env", "to_sb3"]

_PREFIX = "make_"


def _check_autoreset_mode(value: Any) -> AutoresetMode:
    """``value`` as an :class:`AutoresetMode`; ``ValueError`` naming ``autoreset_mode`` and the allowed values."""
    if isinstance(value, AutoresetMode):
        return value
    try:
        return AutoresetMode(value)
    except ValueError:
        allowed = ", ".join(repr(m.value) for m in AutoresetMode)
        raise ValueError(f"autoreset_mode must be an AutoresetMode or one of {allowed}, got {value!r}") from None


class RhsVectorEnv(VectorEnv):
    """``N`` envs stepped in one process, with ``SyncVectorEnv``'s results (seeds, autoreset, merged infos).

    Args:
        env_fns: callables that each make one env (all with the same spaces).
        autoreset_mode: gymnasium's autoreset mode (``NEXT_STEP`` by default, as ``SyncVectorEnv``).
        copy: return copies of the batched observations (as ``SyncVectorEnv``).
        workers: processes that hold and step the envs (1: this process, the envs in :attr:`envs`; more: worker
            processes, :mod:`rhs_env.vector_workers`, and :attr:`envs` is empty).
        context: the workers' multiprocessing start method (``"spawn"`` by default).

    Raises:
        ValueError: no env, a bad ``autoreset_mode`` or ``workers``, or envs whose spaces differ (naming the env).
    """

    def __init__(self, env_fns: Sequence[Callable[[], gym.Env]], autoreset_mode: Any = AutoresetMode.NEXT_STEP,
                 copy: bool = True, workers: int = 1, context: str = "spawn") -> None:
        from rhs_env.vector import check_num_envs
        from rhs_env.vector_workers import EnvWorkers, check_workers

        self.num_envs = check_num_envs(len(env_fns))
        workers = check_workers(workers, self.num_envs)
        self.autoreset_mode = _check_autoreset_mode(autoreset_mode)
        self.copy = bool(copy)
        self.envs: list[gym.Env] = []
        #: the worker processes (None: the envs live in this process)
        self.workers: EnvWorkers | None = None
        try:
            if workers > 1:
                self.workers = EnvWorkers(env_fns, workers, self.autoreset_mode, RhsVectorEnv, context)
            else:
                for fn in env_fns:
                    self.envs.append(fn())
        except BaseException:
            self.close()
            raise
        if self.workers is not None:
            obs_space, act_space = self.workers.observation_space, self.workers.action_space
            metadata, self.render_mode = self.workers.metadata, self.workers.render_mode
        else:
            first = self.envs[0]
            obs_space, act_space, metadata, self.render_mode = (first.observation_space, first.action_space,
                                                                first.metadata, first.render_mode)
        self.metadata = {**metadata, "autoreset_mode": self.autoreset_mode}
        self.single_observation_space = obs_space
        self.single_action_space = act_space
        for i, env in enumerate(self.envs):
            if env.observation_space != self.single_observation_space or env.action_space != self.single_action_space:
                self.close()
                raise ValueError(f"env {i} has other spaces than env 0 (observation {env.observation_space} vs "
                                 f"{self.single_observation_space}, action {env.action_space} vs "
                                 f"{self.single_action_space}); every env of a vector env needs the same spaces")
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._env_obs: list[Any] = [None] * self.num_envs
        self._observations: Any = create_empty_array(self.single_observation_space, n=self.num_envs, fn=np.zeros)
        self._rewards = np.zeros(self.num_envs, dtype=np.float64)
        self._terminations = np.zeros(self.num_envs, dtype=np.bool_)
        self._truncations = np.zeros(self.num_envs, dtype=np.bool_)
        self._autoreset_envs = np.zeros(self.num_envs, dtype=np.bool_)
        #: each env's own info of the last reset / step, and in SAME_STEP mode its final obs / info (else None)
        self.env_infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        self.final_obs: list[Any] = [None] * self.num_envs
        self.final_infos: list[dict[str, Any] | None] = [None] * self.num_envs

    # ------------------------------------------------------------------ gymnasium's API
    def reset(self, *, seed: int | Sequence[int | None] | None = None,
              options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        """Reset every env (or those of ``options["reset_mask"]``); env ``i`` gets ``seed + i`` for an int seed.

        Args:
            seed: ``None`` (fresh seeds), an int (env ``i``: ``seed + i``) or one seed per env.
            options: the envs' reset options; ``"reset_mask"`` (bool array of ``num_envs``) resets only those envs.

        Returns:
            The batched observation and the merged infos.
        """
        seeds = self._seeds(seed)
        options = dict(options) if options is not None else None
        mask = self._reset_mask(options.pop("reset_mask")) if options and "reset_mask" in options \
            else np.ones(self.num_envs, dtype=np.bool_)
        infos: dict[str, Any] = {}
        indices = [int(i) for i in np.flatnonzero(mask)]
        for i, (_, info) in zip(indices, self.reset_envs(indices, [seeds[i] for i in indices], options), strict=True):
            infos = self._add_info(infos, info, i)
        self._observations = concatenate(self.single_observation_space, self._env_obs, self._observations)
        return (deepcopy(self._observations) if self.copy else self._observations), infos

    def step(self, actions: Any) -> tuple[Any, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Step every env with its action (autoreset by :attr:`autoreset_mode`).

        Returns:
            observations, rewards (float64), terminations, truncations, merged infos, as ``SyncVectorEnv``.
        """
        if self._env_obs[0] is None:
            raise RuntimeError("step() before reset(): call reset() first")
        self.step_envs(list(iterate(self.action_space, actions)))
        infos: dict[str, Any] = {}
        for i in range(self.num_envs):
            if self.final_infos[i] is not None:
                infos = self._add_info(infos, {"final_obs": self.final_obs[i], "final_info": self.final_infos[i]}, i)
            infos = self._add_info(infos, self.env_infos[i], i)
        self._observations = concatenate(self.single_observation_space, self._env_obs, self._observations)
        return ((deepcopy(self._observations) if self.copy else self._observations), np.copy(self._rewards),
                np.copy(self._terminations), np.copy(self._truncations), infos)

    def reset_envs(self, indices: Sequence[int], seeds: Sequence[int | None],
                   options: dict[str, Any] | None) -> list[tuple[Any, dict[str, Any]]]:
        """Reset envs ``indices`` with ``seeds`` (one each), wherever they live, writing their per-env buffers
        (observation, info, no final observation, flags cleared); their ``(obs, info)`` in that order."""
        if self.workers is not None:
            results = self.workers.reset(indices, seeds, options)
        else:
            results = [self.envs[i].reset(seed=seed, options=options) for i, seed in zip(indices, seeds, strict=True)]
        for i, (obs, info) in zip(indices, results, strict=True):
            self._env_obs[i], self.env_infos[i], self.final_obs[i], self.final_infos[i] = obs, info, None, None
            self._terminations[i] = self._truncations[i] = self._autoreset_envs[i] = False
        return results

    def step_envs(self, actions: Sequence[Any]) -> None:
        """Step (or autoreset) each env, writing its obs, reward, flags and info into the per-env buffers.

        This is the seam for a batched step over envs: an override writes the same buffers
        (``_env_obs``, ``_rewards``, ``_terminations``, ``_truncations``, :attr:`env_infos`,
        :attr:`final_obs` / :attr:`final_infos` in ``SAME_STEP`` mode, and ``_autoreset_envs``, the envs whose
        episode ended) for all envs at once.
        """
        if self.workers is not None:
            ended = np.flatnonzero(self._autoreset_envs)
            if self.autoreset_mode == AutoresetMode.DISABLED and ended.size:  # refused here: a worker would exit
                raise _disabled_error(int(ended[0]))
            for i, (obs, rew, term, trunc, info, final_obs, final_info) in enumerate(self.workers.step(actions)):
                self._env_obs[i], self._rewards[i], self._terminations[i], self._truncations[i] = obs, rew, term, trunc
                self.env_infos[i], self.final_obs[i], self.final_infos[i] = info, final_obs, final_info
        else:
            self._step_here(actions)
        self._autoreset_envs = np.logical_or(self._terminations, self._truncations)

    def _step_here(self, actions: Sequence[Any]) -> None:
        """:meth:`step_envs` for the envs of this process, in turn."""
        mode = self.autoreset_mode
        for i, (env, action) in enumerate(zip(self.envs, actions, strict=True)):
            self.final_obs[i] = self.final_infos[i] = None
            if mode == AutoresetMode.NEXT_STEP and self._autoreset_envs[i]:
                self._env_obs[i], self.env_infos[i] = env.reset()
                self._rewards[i], self._terminations[i], self._truncations[i] = 0.0, False, False
                continue
            if mode == AutoresetMode.DISABLED and self._autoreset_envs[i]:
                raise _disabled_error(i)
            (self._env_obs[i], self._rewards[i], self._terminations[i], self._truncations[i],
             self.env_infos[i]) = env.step(action)
            if mode == AutoresetMode.SAME_STEP and (self._terminations[i] or self._truncations[i]):
                self.final_obs[i], self.final_infos[i] = self._env_obs[i], self.env_infos[i]
                self._env_obs[i], self.env_infos[i] = env.reset()

    def render(self) -> tuple[Any, ...]:
        """Each env's frame."""
        if self.workers is not None:
            return tuple(self.workers.render())
        return tuple(env.render() for env in self.envs)

    def call(self, name: str, *args: Any, **kwargs: Any) -> tuple[Any, ...]:
        """Call (or read, when not callable) ``name`` of each env."""
        return tuple(self.call_at(range(self.num_envs), name, args, kwargs))

    def get_attr(self, name: str) -> tuple[Any, ...]:
        """``name`` of each env."""
        return tuple(self.get_attr_at(range(self.num_envs), name))

    def set_attr(self, name: str, values: Any) -> None:
        """Set ``name`` of each env to ``values`` (one value, or a list of one per env)."""
        if not isinstance(values, (list, tuple)):
            values = [values] * self.num_envs
        if len(values) != self.num_envs:
            raise ValueError(f"set_attr({name!r}): {len(values)} values for {self.num_envs} envs")
        self.set_attr_at(range(self.num_envs), name, list(values))

    def call_at(self, indices: Sequence[int], name: str, args: Sequence[Any] = (),
                kwargs: dict[str, Any] | None = None) -> list[Any]:
        """Call (or read, when not callable) ``name`` of envs ``indices``, wherever they live."""
        if self.workers is not None:
            return self.workers.call(list(indices), name, tuple(args), kwargs)
        out = []
        for i in indices:
            attr = self.envs[i].get_wrapper_attr(name)
            out.append(attr(*args, **(kwargs or {})) if callable(attr) else attr)
        return out

    def get_attr_at(self, indices: Sequence[int], name: str) -> list[Any]:
        """``name`` of envs ``indices``."""
        if self.workers is not None:
            return self.workers.get_attr(list(indices), name)
        return [self.envs[i].get_wrapper_attr(name) for i in indices]

    def set_attr_at(self, indices: Sequence[int], name: str, values: Sequence[Any]) -> None:
        """Set ``name`` of envs ``indices`` to ``values`` (one each)."""
        if self.workers is not None:
            self.workers.set_attr(list(indices), name, list(values))
            return
        for i, value in zip(indices, values, strict=True):
            self.envs[i].set_wrapper_attr(name, value)

    def is_wrapped_at(self, indices: Sequence[int], wrapper: type) -> list[bool]:
        """Whether envs ``indices`` are wrapped in ``wrapper`` (a ``gymnasium.Wrapper`` class)."""
        if self.workers is not None:
            return self.workers.is_wrapped(list(indices), wrapper)
        out = []
        for i in indices:
            env: Any = self.envs[i]
            found = False
            while isinstance(env, gym.Wrapper):
                found = found or isinstance(env, wrapper)
                env = env.env
            out.append(found)
        return out

    def close_extras(self, **kwargs: Any) -> None:
        """Close every env (and the worker processes)."""
        for env in getattr(self, "envs", []):
            env.close()
        if getattr(self, "workers", None) is not None:
            self.workers.close()  # type: ignore[union-attr]
            self.workers = None

    # ------------------------------------------------------------------ helpers
    def _seeds(self, seed: int | Sequence[int | None] | None) -> list[int | None]:
        if seed is None:
            return [None] * self.num_envs
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, (bool, np.bool_)):
            return [int(seed) + i for i in range(self.num_envs)]
        seeds = list(seed)  # type: ignore[arg-type]
        if len(seeds) != self.num_envs:
            raise ValueError(f"seed: a list of seeds needs one per env ({self.num_envs}), got {len(seeds)}")
        return seeds

    def _reset_mask(self, mask: Any) -> np.ndarray:
        if not isinstance(mask, np.ndarray) or mask.dtype != np.bool_ or mask.shape != (self.num_envs,):
            raise ValueError(f"options['reset_mask'] must be a bool numpy array of shape ({self.num_envs},), got "
                             f"{mask!r}")
        if not mask.any():
            raise ValueError("options['reset_mask'] must have at least one True (an env to reset)")
        return mask

    def __repr__(self) -> str:
        spec = getattr(self, "spec", None)
        return f"RhsVectorEnv({spec.id + ', ' if spec is not None else ''}num_envs={self.num_envs})"


def _disabled_error(i: int) -> RuntimeError:
    return RuntimeError(f"env {i} ended and autoreset_mode is DISABLED: reset it first "
                        "(reset(options={'reset_mask': mask}))")


def make_vector_env(env_id: str, num_envs: int = 1, autoreset_mode: Any = AutoresetMode.NEXT_STEP,
                    copy: bool = True, workers: int = 1, context: str = "spawn", **kwargs: Any) -> RhsVectorEnv:
    """:class:`RhsVectorEnv` of ``num_envs`` envs ``gym.make(env_id, **kwargs)`` (the vector entry point).

    Args:
        env_id: a registered id.
        num_envs: envs, [1, :data:`rhs_env.vector.MAX_ENVS`].
        autoreset_mode: gymnasium's autoreset mode (default ``NEXT_STEP``).
        copy: return copies of the observations.
        workers: processes that step the envs (1: this process; :mod:`rhs_env.vector_workers`).
        context: the workers' multiprocessing start method.
        **kwargs: every env's kwargs (as for ``gym.make``: config keys, ``radar={...}``, ``max_episode_steps``).

    Returns:
        The vector env.

    Raises:
        ValueError: ``num_envs`` or ``workers`` out of range, an unstackable info flag (``landmarks_in_info``),
            a bad kwarg.
    """
    from rhs_env.vector import check_num_envs
    from rhs_env.vector_workers import check_workers

    n = check_num_envs(num_envs)
    check_workers(workers, n)
    check_vector_info_flags(kwargs, force=True)
    return RhsVectorEnv([functools.partial(gym.make, env_id, **kwargs)] * n, autoreset_mode=autoreset_mode,
                        copy=copy, workers=workers, context=context)


def __getattr__(name: str) -> Any:
    """``make_<id with _>``: :func:`make_vector_env` for that id (gymnasium resolves the entry point by name)."""
    if name.startswith(_PREFIX + "rhs_"):
        env_id = name[len(_PREFIX):].replace("_", "-")
        if env_id in gym.registry:
            return functools.partial(make_vector_env, env_id)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


# --------------------------------------------------------------------------- stable-baselines3
def to_sb3(vec_env: RhsVectorEnv) -> Any:
    """A stable-baselines3 ``VecEnv`` over ``vec_env`` (which must autoreset in ``SAME_STEP`` mode).

    SB3's contract: ``reset()`` returns the observation only (seeds from ``seed()``), ``step`` returns ``dones``
    (terminated or truncated), and an ended env's info holds ``terminal_observation`` and
    ``TimeLimit.truncated``, its observation already that of the next episode.

    Args:
        vec_env: an :class:`RhsVectorEnv` made with ``autoreset_mode="SameStep"``
            (``gym.make_vec(id, N, vectorization_mode="vector_entry_point", autoreset_mode="SameStep")``).

    Returns:
        The ``VecEnv``; closing it closes ``vec_env``.

    Raises:
        TypeError: ``vec_env`` is not an :class:`RhsVectorEnv`.
        ValueError: its autoreset mode is not ``SAME_STEP``.
    """
    if not isinstance(vec_env, RhsVectorEnv):
        raise TypeError(f"to_sb3 takes an RhsVectorEnv (gym.make_vec(..., vectorization_mode='vector_entry_point')), "
                        f"got {type(vec_env).__name__}")
    if vec_env.autoreset_mode != AutoresetMode.SAME_STEP:
        raise ValueError(f"to_sb3 needs the vector env's autoreset_mode SAME_STEP (SB3 resets an ended env in the "
                         f"same step), got {vec_env.autoreset_mode}; make it with autoreset_mode='SameStep'")
    return _sb3_class()(vec_env)


@functools.cache
def _sb3_class() -> type:
    """The adapter class, built on first use: importing this module does not import stable-baselines3 (torch)."""
    from stable_baselines3.common.vec_env.base_vec_env import VecEnv

    class Sb3VecEnv(VecEnv):
        """stable-baselines3's ``VecEnv`` over an :class:`RhsVectorEnv` in ``SAME_STEP`` mode."""

        def __init__(self, vec_env: RhsVectorEnv) -> None:
            self.vec_env = vec_env
            self.render_mode = vec_env.render_mode
            super().__init__(vec_env.num_envs, vec_env.single_observation_space, vec_env.single_action_space)
            self.metadata = vec_env.metadata
            self._actions: Any = None

        def reset(self) -> Any:
            seeds = [s if s is None else int(s) for s in self._seeds]
            options = self._options[0] if self._options and all(o == self._options[0] for o in self._options) \
                else None
            if any(self._options) and options is None:
                raise ValueError("per-env reset options differ; the native vector env takes one options dict")
            obs, _ = self.vec_env.reset(seed=seeds, options=options or None)
            self.reset_infos = [dict(i) for i in self.vec_env.env_infos]
            self._reset_seeds()
            self._reset_options()
            return obs

        def step_async(self, actions: np.ndarray) -> None:
            self._actions = actions

        def step_wait(self) -> Any:
            obs, rewards, terms, truncs, _ = self.vec_env.step(self._actions)
            dones = terms | truncs
            infos: list[dict[str, Any]] = []
            for i in range(self.num_envs):
                if dones[i]:
                    info = dict(self.vec_env.final_infos[i] or {})
                    info["terminal_observation"] = self.vec_env.final_obs[i]
                    self.reset_infos[i] = dict(self.vec_env.env_infos[i])
                else:
                    info = dict(self.vec_env.env_infos[i])
                info["TimeLimit.truncated"] = bool(truncs[i] and not terms[i])
                infos.append(info)
            return obs, rewards.astype(np.float32), dones, infos

        def close(self) -> None:
            self.vec_env.close()

        def get_images(self) -> Sequence[np.ndarray | None]:
            return list(self.vec_env.render())

        def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
            return self.vec_env.get_attr_at(list(self._get_indices(indices)), attr_name)

        def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
            targets = list(self._get_indices(indices))
            self.vec_env.set_attr_at(targets, attr_name, [value] * len(targets))

        def env_method(self, method_name: str, *method_args: Any, indices: Any = None, **method_kwargs: Any) -> list[Any]:
            return self.vec_env.call_at(list(self._get_indices(indices)), method_name, method_args, method_kwargs)

        def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: Any = None) -> list[bool]:
            return self.vec_env.is_wrapped_at(list(self._get_indices(indices)), wrapper_class)

    Sb3VecEnv.__module__ = __name__
    return Sb3VecEnv
