"""A training run's hyperparameters: the ``agents/hyperparams/<algo>.yml`` entry of an env id, checked and
resolved into the run's :class:`RunSettings`.

The files are rl-baselines3-zoo style: one entry per env id with ``policy``, ``n_envs``, ``n_timesteps``,
``env_kwargs``, ``policy_kwargs`` (a zoo expression, parsed without running it by
:mod:`agents.algos.policy_kwargs`), ``lin_<value>`` learning-rate and clip-range schedules (linear from the value
down to 0 over the run), ``decision_interval`` / ``decision_mode`` (:mod:`agents.policies.decision`) and the
algorithm's own arguments. :func:`load_hyperparams` reads and checks an entry (numbers of the wrong type or
range name ``FILE: ENV_ID.KEY``, :data:`HP_NUMBERS`), :func:`run_settings` merges it with the caller's arguments.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = [
    "ALGOS", "HP_NUMBERS", "HP_SCHEDULES", "HYPERPARAMS_DIR", "META_KEYS", "RunSettings", "check_hyperparams",
    "eval_policy_kwargs", "load_hyperparams", "policy_kwargs_by_name", "resolve_policy_kwargs", "run_settings",
]

ALGOS = ("ppo", "dqn", "dagger", "finetune")
HYPERPARAMS_DIR = Path(__file__).parent.parent / "hyperparams"  # agents/hyperparams/, beside the subpackages
#: keys of a hyperparameter entry that are not arguments of the algorithm class
META_KEYS = ("policy", "n_envs", "n_timesteps", "env_kwargs", "decision_interval", "decision_mode")


def load_hyperparams(algo: str, env_id: str, path: str | Path | None = None) -> dict[str, Any]:
    """Hyperparameters for ``env_id`` from a zoo-style YAML file (default: the shipped one for ``algo``)."""
    from rhs_common.input_files import read_yaml
    from rhs_env.registration import check_env_id

    if algo not in ALGOS:
        raise ValueError(f"algo must be one of {ALGOS}, got {algo!r}")
    check_env_id(env_id)
    path = Path(path) if path else HYPERPARAMS_DIR / f"{algo}.yml"
    if not path.exists():
        raise ValueError(f"hyperparameter file not found: {path}")
    table = read_yaml(path) or {}
    if not isinstance(table, dict):
        raise ValueError(f"{path}: must map env ids to hyperparameter entries, got a {type(table).__name__}")  # noqa: TRY004
    key = env_id.split(":", 1)[-1]
    if key not in table:
        raise ValueError(f"{path} has no hyperparameters for env {key!r} (has: {', '.join(map(str, table))})")
    if not isinstance(table[key], dict):
        raise ValueError(f"{path}: entry {key!r} must be a mapping of hyperparameters, got {table[key]!r}")  # noqa: TRY004
    hp = dict(table[key])
    if "policy" not in hp:
        raise ValueError(f"{path}: entry {key!r} has no 'policy'")
    check_hyperparams(hp, f"{path}: {key}")
    if isinstance(hp.get("policy_kwargs"), str):  # refused here, naming the file, before anything else reads it
        eval_policy_kwargs(hp["policy_kwargs"], f"{path}: {key}.policy_kwargs")
    return hp


#: the numeric hyperparameters (stable-baselines3's PPO / DQN, DAgger's, this project's): integer or not,
#: and the allowed range; a string or a boolean there would fail deep inside the algorithm
HP_NUMBERS: dict[str, tuple[bool, float, float]] = {
    "n_timesteps": (True, 1, 10**9), "n_envs": (True, 1, 256), "n_steps": (True, 1, 10**6),
    "batch_size": (True, 1, 10**6), "n_epochs": (True, 1, 10_000), "gamma": (False, 0.0, 1.0),
    "gae_lambda": (False, 0.0, 1.0), "ent_coef": (False, 0.0, 1.0), "vf_coef": (False, 0.0, 100.0),
    "max_grad_norm": (False, 0.0, 1e6), "buffer_size": (True, 1, 10**9), "learning_starts": (True, 0, 10**9),
    "gradient_steps": (True, -1, 10**6), "target_update_interval": (True, 1, 10**9),
    "exploration_fraction": (False, 0.0, 1.0), "exploration_initial_eps": (False, 0.0, 1.0),
    "exploration_final_eps": (False, 0.0, 1.0), "tau": (False, 0.0, 1.0), "decision_interval": (True, 1, 10_000),
    "iterations": (True, 1, 10_000), "beta_decay": (False, 0.0, 1.0), "epochs": (True, 1, 100_000),
    "class_weight_power": (False, 0.0, 100.0), "anchor_coef": (False, 0.0, 1e3), "anchor_fraction": (False, 0.0, 1.0),
    "anchor_epochs": (True, 0, 100), "prior_steps": (True, 1, 10**7), "critic_warmup_fraction": (False, 0.0, 1.0),
}
#: numbers that may also be written ``lin_<number>`` (a linear schedule down to 0)
HP_SCHEDULES = {"learning_rate": 1.0, "clip_range": 100.0}


def check_hyperparams(hp: dict[str, Any], where: str) -> None:
    """``TypeError`` / ``ValueError`` naming ``where.key`` for a numeric hyperparameter of the wrong type or range."""
    from rhs_common.validation import check_int, check_range

    for key, (integer, low, high) in HP_NUMBERS.items():
        if key in hp and integer:
            check_int(f"{where}.{key}", hp[key], int(low), int(high))
        elif key in hp:
            check_range(f"{where}.{key}", hp[key], low, high)
    for key, high in HP_SCHEDULES.items():
        value = hp.get(key)
        if isinstance(value, str) and value.startswith("lin_"):
            try:
                value = float(value[4:])
            except ValueError:
                raise ValueError(f"{where}.{key} must be a number or 'lin_<number>', got {hp[key]!r}") from None
        if key in hp:
            if isinstance(value, str):
                raise TypeError(f"{where}.{key} must be a number or 'lin_<number>', got {value!r}")
            check_range(f"{where}.{key}", value, 0.0, high, low_open=True)


def _linear_schedule(initial: float):
    def schedule(progress_remaining: float) -> float:
        return progress_remaining * initial

    return schedule


def _resolve_schedules(hp: dict[str, Any]) -> dict[str, Any]:
    """zoo-style ``"lin_5e-4"`` values -> linear schedules from that value to 0."""
    out = dict(hp)
    for key in ("learning_rate", "clip_range"):
        value = out.get(key)
        if isinstance(value, str):
            if not value.startswith("lin_"):
                raise ValueError(f"{key} must be a number or 'lin_<number>', got {value!r}")
            out[key] = _linear_schedule(float(value[4:]))
    return out


def eval_policy_kwargs(text: str, where: str = "policy_kwargs") -> dict[str, Any]:
    """A zoo-style ``policy_kwargs`` string -> dict, parsed without running it
    (:func:`agents.algos.policy_kwargs.parse_policy_kwargs`: literals, ``dict(...)`` and a fixed set of names such as
    ``nn.ReLU`` or ``importlib.import_module('agents.features').PointSetExtractor``; ``ValueError`` naming
    ``where`` for anything else)."""
    from agents.algos.policy_kwargs import parse_policy_kwargs

    return parse_policy_kwargs(text, where)


def resolve_policy_kwargs(kwargs: dict[str, Any] | str) -> dict[str, Any]:
    from agents.policies.features import FEATURE_EXTRACTORS

    if isinstance(kwargs, str):
        kwargs = eval_policy_kwargs(kwargs)
    kwargs = dict(kwargs or {})
    name = kwargs.get("features_extractor_class")
    if isinstance(name, str):
        if name not in FEATURE_EXTRACTORS:
            raise ValueError(f"features_extractor_class must be one of {list(FEATURE_EXTRACTORS)}, got {name!r}")
        kwargs["features_extractor_class"] = FEATURE_EXTRACTORS[name]
    return kwargs


def policy_kwargs_by_name(kwargs: dict[str, Any] | str) -> dict[str, Any]:
    """``policy_kwargs`` with the extractor by its registered name (``"point_set"``), as the RLlib backend takes it.

    The shipped YAML writes it as rl-baselines3-zoo's Python expression naming the class.
    """
    from agents.policies.features import FEATURE_EXTRACTORS

    kwargs = dict(eval_policy_kwargs(kwargs) if isinstance(kwargs, str) else (kwargs or {}))
    cls = kwargs.get("features_extractor_class")
    if cls is not None and not isinstance(cls, str):
        names = [name for name, c in FEATURE_EXTRACTORS.items() if c is cls]
        if not names:
            raise ValueError(f"features_extractor_class must be one of {list(FEATURE_EXTRACTORS)}, got {cls!r}")
        kwargs["features_extractor_class"] = names[0]
    return kwargs


@dataclass(frozen=True)
class RunSettings:
    """What a training run uses, from the YAML merged with the caller's arguments."""

    policy: str
    timesteps: int
    n_envs: int
    env_kwargs: dict[str, Any]
    hp: dict[str, Any]  # constructor kwargs of the algorithm (schedules and policy_kwargs resolved)
    hp_record: dict[str, Any]  # the YAML as written, for the summary
    decision_interval: int = 1  # env steps per agent decision (agents.policies.decision.HoldAction)
    decision_mode: str = "hold"  # between decisions: the action repeated, or IDLE after it ("pulse")


def run_settings(algo: str, env_id: str, timesteps: int | None, n_envs: int | None,
                  hyperparams: str | Path | None, env_kwargs: dict | None) -> RunSettings:
    from agents.policies.decision import check_decision_interval, check_decision_mode

    hp = load_hyperparams(algo, env_id, hyperparams)
    policy = hp.pop("policy")
    k = check_decision_interval(hp.pop("decision_interval", 1))
    mode = check_decision_mode(hp.pop("decision_mode", "hold"))
    yaml_steps = hp.pop("n_timesteps", None)
    steps = int(timesteps if timesteps is not None else (yaml_steps or 0))
    if steps < 1:
        raise ValueError(f"timesteps must be >= 1, got {steps}")
    yaml_envs = hp.pop("n_envs", 1)
    envs = int(n_envs if n_envs is not None else yaml_envs)
    if envs < 1:
        raise ValueError(f"n_envs must be >= 1, got {envs}")
    kwargs = {**(hp.pop("env_kwargs", None) or {}), **(env_kwargs or {})}
    hp["policy_kwargs"] = resolve_policy_kwargs(hp.get("policy_kwargs", {}))
    record = {k: v for k, v in load_hyperparams(algo, env_id, hyperparams).items() if k not in META_KEYS}
    return RunSettings(policy, steps, envs, kwargs, _resolve_schedules(hp), record, k, mode)
