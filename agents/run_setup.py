"""The old path of the training run's set-up, kept for code and commands written before :mod:`agents.algos`.

``agents.run_setup`` was one module; its parts are now the modules of their concern, and this module re-exports
every public name it had, so ``from agents.run_setup import make_vec_env`` still works:

* :mod:`agents.algos.hyperparams`: the YAML entries and the run's settings (``load_hyperparams``,
  ``run_settings``, ``RunSettings``, the policy kwargs);
* :mod:`agents.algos.vec_env`: the vector envs and their workers (``make_vec_env``, ``EnvFactory``,
  ``warm_kernels``);
* :mod:`agents.algos.run_checks`: the argument checks (``parse_env_kwargs``, ``check_train_args``,
  ``check_env_kwargs``, ``shield_setting``);
* :mod:`agents.algos.run_records`: what a run writes (``run_summary``, ``run_record``, ``write_summary``);
* :mod:`agents.algos.threads`: the threads (``limit_threads``, ``update_threads_for``).
"""

from __future__ import annotations

from agents.algos.hyperparams import (
    ALGOS,
    HP_NUMBERS,
    HP_SCHEDULES,
    HYPERPARAMS_DIR,
    META_KEYS,
    RunSettings,
    check_hyperparams,
    eval_policy_kwargs,
    load_hyperparams,
    policy_kwargs_by_name,
    resolve_policy_kwargs,
    run_settings,
)
from agents.algos.run_checks import check_env_kwargs, check_train_args, parse_env_kwargs, shield_setting
from agents.algos.run_records import metadata_path, run_record, run_summary, tensorboard_available, write_summary
from agents.algos.threads import limit_threads, update_threads_for
from agents.algos.vec_env import (
    FORKSERVER_PRELOAD,
    WARM_STEPS,
    EnvFactory,
    make_vec_env,
    start_forkserver_ignoring_sigint,
    warm_kernels,
    worker_env_id,
)

__all__ = [
    "ALGOS", "EnvFactory", "FORKSERVER_PRELOAD", "HP_NUMBERS", "HP_SCHEDULES", "HYPERPARAMS_DIR", "META_KEYS",
    "RunSettings", "WARM_STEPS", "check_env_kwargs", "check_hyperparams", "check_train_args", "eval_policy_kwargs",
    "limit_threads", "load_hyperparams", "make_vec_env", "metadata_path", "parse_env_kwargs", "policy_kwargs_by_name",
    "resolve_policy_kwargs", "run_record", "run_settings", "run_summary", "shield_setting",
    "start_forkserver_ignoring_sigint", "tensorboard_available", "update_threads_for", "warm_kernels", "worker_env_id",
    "write_summary",
]
