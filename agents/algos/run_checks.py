"""The checks of a training run's arguments before any worker starts, each error naming what is wrong.

:func:`parse_env_kwargs` (the ``--env-kwargs`` JSON), :func:`check_train_args` (the bounds that keep a run finite),
:func:`check_env_kwargs` (one env built and closed here, so bad env kwargs fail readably) and
:func:`shield_setting` (the run's radar shield record, refused on an env without radar points).
"""

from __future__ import annotations

from typing import Any

__all__ = ["check_env_kwargs", "check_train_args", "parse_env_kwargs", "shield_setting"]


def parse_env_kwargs(text: str | None) -> dict[str, Any] | None:
    """``--env-kwargs`` JSON -> dict (``None`` when not given); ``ValueError`` naming ``--env-kwargs``."""
    from rhs_common.input_files import parse_json

    if text is None:
        return None
    value = parse_json(text, "--env-kwargs")
    if not isinstance(value, dict):
        raise ValueError(f"--env-kwargs must be a JSON object, got {type(value).__name__}")  # noqa: TRY004
    return value


def check_train_args(timesteps: int, n_envs: int, seed: int, eval_freq: int, eval_episodes: int,
                     checkpoint_freq: int) -> None:
    """Bounds that keep a training run finite (``ValueError`` / ``TypeError`` naming the argument)."""
    from rhs_common.validation import check_int

    check_int("timesteps", timesteps, 1, 10**9)
    check_int("n_envs", n_envs, 1, 256)
    check_int("seed", seed, 0, 2**32 - 1)  # numpy's legacy seeding inside stable-baselines3
    check_int("eval_freq", eval_freq, 0, 10**9)
    check_int("eval_episodes", eval_episodes, 1, 10_000)
    check_int("checkpoint_freq", checkpoint_freq, 0, 10**9)


def check_env_kwargs(env_id: str, env_kwargs: dict[str, Any]) -> None:
    """Build and close one env here, so bad ``env_kwargs`` raise a readable error before workers start."""
    import gymnasium as gym

    import rhs_env  # noqa: F401

    try:
        env = gym.make(env_id.split(":", 1)[-1] if env_id.startswith("rhs_env:") else env_id, **env_kwargs)
    except TypeError as exc:
        raise ValueError(f"bad env_kwargs for {env_id}: {exc}") from None
    env.close()


def shield_setting(env_id: str, hp: dict[str, Any], env_kwargs: dict[str, Any]) -> dict[str, Any] | None:
    """The run's radar shield (the YAML entry ``hp``'s ``shield``) as its full record (None: none), validated: a wrong
    field names ``shield.<field>``, and an env without radar points (one built with ``env_kwargs``) is refused."""
    from agents.policies.shield import check_shield_env, shield_record

    shield = shield_record(hp.get("shield"))
    if shield is None:
        return None
    import gymnasium as gym

    import rhs_env  # noqa: F401  (registers the ids)

    env = gym.make(env_id, **env_kwargs)
    try:
        check_shield_env(env.observation_space)
    finally:
        env.close()
    return shield
