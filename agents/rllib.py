"""Ray RLlib backend for ``rhs-slam train --backend rllib`` (training beyond one machine).

PPO on RLlib's new API stack (``EnvRunner`` actors sample, a ``Learner`` updates):

* the env is registered with ``ray.tune.register_env(<gym id>, creator)``; the
  creator imports ``rhs_env`` (which registers the gym ids in each Ray worker)
  and calls ``gym.make(<id>, **env_config)``; ``env_config`` is the training
  ``env_kwargs``, so a worker on another machine rebuilds exactly the same env;
* observations reach the policy unflattened: :class:`PointSetPPOModule` (a
  ``TorchRLModule`` with RLlib's ``ValueFunctionAPI``) encodes Dict observations
  with the masked point-set encoder of :mod:`agents.features` (the one the
  stable-baselines3 backend uses, permutation invariant, padding ignored) and
  Box observations by flattening; separate policy and value MLPs
  (``net_arch``) sit on the shared encoding;
* hyperparameters come from the same ``agents/hyperparams/ppo.yml`` entry as the
  SB3 backend, mapped as: rollout ``n_steps * n_envs`` -> ``train_batch_size``,
  ``batch_size`` -> ``minibatch_size``, ``n_epochs`` -> ``num_epochs``,
  ``gae_lambda`` -> ``lambda_``, ``clip_range`` -> ``clip_param``, ``ent_coef``
  -> ``entropy_coeff``, ``lin_<lr>`` -> a linear schedule to 0 over the run;
* ``address=None`` starts a local Ray instance (``num_env_runners + 1`` CPUs);
  ``address="auto"`` or ``"ray://host:10001"`` / ``"host:6379"`` joins an existing
  cluster, whose nodes must have this package installed (same version).

What scales with machines: sampling (each env runner is a Ray actor holding its
own env copy, placed on any node with a free CPU), so env steps/s grow with
``num_env_runners`` until the single learner's update time dominates. What does
not: the PPO update (one learner here; ``--num-learners`` style data
parallelism is not wired) and the synchronous gather of each iteration (an
iteration waits for the slowest runner).

Writes into ``DIR``: ``rllib_checkpoint/`` (``Algorithm.save_to_path``; its
RLModule is what ``rhs-slam evaluate --policy DIR/rllib_checkpoint`` loads),
``rllib_checkpoint.json`` beside it and ``train.json`` (env id, env kwargs,
settings, timings, per-iteration progress), ``checkpoints/step_<n>/`` every
``checkpoint_freq`` env steps, ``tb/`` (TensorBoard scalars per iteration).

Works with gymnasium 1.2 (ray[rllib] 2.60's pin) and 1.4 (the base install).
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

CHECKPOINT_DIR = "rllib_checkpoint"
#: the RLModule inside an algorithm checkpoint (single-agent: the default module id)
MODULE_SUBDIR = ("learner_group", "learner", "rl_module", "default_policy")


def require_ray():
    """Import ray, or raise ``ValueError`` telling how to install the extra."""
    try:
        import ray
        from ray.rllib.algorithms.ppo import PPOConfig  # noqa: F401
    except ImportError as exc:
        raise ValueError(
            f"the rllib backend needs Ray RLlib ({exc}): pip install torch==2.13.0 && pip install -e '.[rllib]'"
        ) from None
    return ray


def make_env(env_id: str, env_config: dict[str, Any] | None = None) -> gym.Env:
    """The creator registered with ``ray.tune.register_env``: ``gym.make(env_id, **env_config)``."""
    import rhs_env  # noqa: F401  (registers the rhs ids in this worker)

    return gym.make(env_id, **dict(env_config or {}))


def _encoder(observation_space: gym.spaces.Space, model_config: dict[str, Any]):
    """Masked point-set encoder for Dict observations, flatten for Box ones; returns (module, width)."""
    from torch import nn

    from agents.features import PointSetExtractor

    if isinstance(observation_space, gym.spaces.Dict):
        enc = PointSetExtractor(observation_space, **dict(model_config.get("features_extractor_kwargs") or {}))
        return enc, enc.features_dim
    return nn.Flatten(), int(np.prod(observation_space.shape or ()))


def _mlp(width: int, hidden: list[int], out: int, gain: float):
    from torch import nn

    layers: list = []
    for h in hidden:
        layers += [nn.Linear(width, h), nn.Tanh()]
        width = h
    last = nn.Linear(width, out)
    nn.init.orthogonal_(last.weight, gain=gain)
    nn.init.zeros_(last.bias)
    return nn.Sequential(*layers, last)


try:  # Ray is an optional extra: the module class exists where it is installed
    from ray.rllib.core.columns import Columns
    from ray.rllib.core.rl_module.apis import ValueFunctionAPI
    from ray.rllib.core.rl_module.torch import TorchRLModule
except ImportError:  # pragma: no cover  (base install)
    TorchRLModule = None

if TorchRLModule is not None:

    class PointSetPPOModule(TorchRLModule, ValueFunctionAPI):
        """Shared encoder (point-set or flatten) -> policy MLP (logits) and value MLP (scalar).

        ``model_config``: ``net_arch`` (hidden widths of both heads, default [64, 64]),
        ``features_extractor_kwargs`` (``point_dim``, ``box_dim`` of the point-set encoder).
        Output gains follow SB3's PPO: 0.01 for the logits, 1 for the value.
        """

        def setup(self):
            cfg = dict(self.model_config or {})
            hidden = list(cfg.get("net_arch") or [64, 64])
            self.encoder, width = _encoder(self.observation_space, cfg)
            self.pi = _mlp(width, hidden, int(self.action_space.n), 0.01)
            self.vf = _mlp(width, hidden, 1, 1.0)

        def _encode(self, batch):
            obs = batch[Columns.OBS]
            if isinstance(obs, dict):
                return self.encoder({k: v.float() for k, v in obs.items()})
            return self.encoder(obs.float())

        def _forward(self, batch, **kwargs):
            return {Columns.ACTION_DIST_INPUTS: self.pi(self._encode(batch))}

        def _forward_train(self, batch, **kwargs):
            emb = self._encode(batch)
            return {Columns.ACTION_DIST_INPUTS: self.pi(emb), Columns.EMBEDDINGS: emb}

        def compute_values(self, batch, embeddings=None):
            if embeddings is None:
                embeddings = self._encode(batch)
            return self.vf(embeddings).squeeze(-1)


def ppo_settings(hp: dict[str, Any], n_envs: int, timesteps: int) -> dict[str, Any]:
    """The SB3-style YAML entry (``hp``, without the meta keys) as RLlib PPO settings."""
    known = {"n_steps", "batch_size", "n_epochs", "learning_rate", "gamma", "gae_lambda", "clip_range",
             "ent_coef", "vf_coef", "max_grad_norm", "policy_kwargs"}  # fmt: skip
    unknown = sorted(set(hp) - known)
    if unknown:
        raise ValueError(f"hyperparameters not supported by the rllib backend: {', '.join(unknown)}")
    lr = hp.get("learning_rate", 3e-4)
    if isinstance(lr, str):
        if not lr.startswith("lin_"):
            raise ValueError(f"learning_rate must be a number or 'lin_<number>', got {lr!r}")
        lr = [[0, float(lr[4:])], [int(timesteps), 0.0]]
    if isinstance(hp.get("clip_range"), str):
        raise ValueError("the rllib backend takes a constant clip_range")  # noqa: TRY004  (a usage error)
    train_batch = int(hp.get("n_steps", 2048)) * int(n_envs)
    return {
        "train_batch_size_per_learner": train_batch,
        "minibatch_size": min(int(hp.get("batch_size", 64)), train_batch),
        "num_epochs": int(hp.get("n_epochs", 10)),
        "lr": lr,
        "gamma": float(hp.get("gamma", 0.99)),
        "lambda_": float(hp.get("gae_lambda", 0.95)),
        "clip_param": float(hp.get("clip_range", 0.2)),
        "entropy_coeff": float(hp.get("ent_coef", 0.0)),
        "vf_loss_coeff": float(hp.get("vf_coef", 0.5)),
        "grad_clip": float(hp.get("max_grad_norm", 0.5)),
    }


if TorchRLModule is not None:
    from ray.rllib.callbacks.callbacks import RLlibCallback

    class CrashRateCallback(RLlibCallback):
        """Logs ``crash_rate``: the mean of ``info["crashed"]`` at the end of the recent episodes."""

        def on_episode_end(self, *, episode, metrics_logger=None, **kwargs) -> None:
            if metrics_logger is None:
                return
            info = episode.get_infos(-1) or {}
            metrics_logger.log_value("crash_rate", float(bool(info.get("crashed", False))), reduce="mean", window=100)


def build_config(
    env_id: str,
    env_kwargs: dict[str, Any],
    settings: dict[str, Any],
    model_config: dict[str, Any],
    num_env_runners: int,
    seed: int,
    eval_interval: int = 0,
    eval_episodes: int = 3,
):
    """The ``PPOConfig``: env registered by its gym id, the point-set RLModule, one local learner."""
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.core.rl_module.rl_module import RLModuleSpec
    from ray.tune.registry import register_env

    register_env(env_id, lambda cfg, _id=env_id: make_env(_id, dict(cfg)))
    config = (
        PPOConfig()
        .environment(env=env_id, env_config=dict(env_kwargs))
        .framework("torch")
        .env_runners(
            num_env_runners=int(num_env_runners),
            num_envs_per_env_runner=1,
            num_cpus_per_env_runner=1,
            rollout_fragment_length="auto",
            sample_timeout_s=3600.0,
        )
        .learners(num_learners=0)
        .training(**settings)
        .rl_module(rl_module_spec=RLModuleSpec(module_class=PointSetPPOModule, model_config=dict(model_config)))
        .callbacks(CrashRateCallback)
        .debugging(seed=int(seed))
        .reporting(metrics_num_episodes_for_smoothing=100)
    )
    if eval_interval > 0:
        config = config.evaluation(
            evaluation_interval=int(eval_interval),
            evaluation_duration=int(eval_episodes),
            evaluation_duration_unit="episodes",
            evaluation_num_env_runners=0,
            evaluation_config={"explore": False},
        )
    return config


def _iteration_record(result: dict[str, Any], wall: float) -> dict[str, Any]:
    """Steps, episode return / length / crash rate (recent episodes) and timing of one ``algo.train()``."""
    er = result.get("env_runners") or {}
    steps = result.get("num_env_steps_sampled_lifetime", er.get("num_env_steps_sampled_lifetime"))
    ev = (result.get("evaluation") or {}).get("env_runners") or {}

    def num(x):
        return None if x is None or not np.isfinite(float(x)) else float(x)

    return {
        "iteration": int(result.get("training_iteration", 0)),
        "env_steps": int(steps or 0),
        "wall_s": round(wall, 2),
        "episode_return_mean": num(er.get("episode_return_mean")),
        "episode_len_mean": num(er.get("episode_len_mean")),
        "crash_rate": num(er.get("crash_rate")),
        "eval_return_mean": num(ev.get("episode_return_mean")),
    }


def init_ray(address: str | None, num_env_runners: int):
    """Join the cluster at ``address`` or start a local instance; returns whether we started it."""
    ray = require_ray()
    env_vars = {k: os.environ.get(k, "1") for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")}
    if ray.is_initialized():
        return False
    runtime_env = {"env_vars": env_vars}
    if address:
        ray.init(address=address, runtime_env=runtime_env, log_to_driver=False)
        return True
    # Ray gives a new local node 30 s (hard-coded) to register; on an overloaded machine it
    # can miss that: try again from scratch a few times before giving up
    for attempt in range(LOCAL_START_ATTEMPTS):
        try:
            ray.init(num_cpus=int(num_env_runners) + 1, include_dashboard=False, runtime_env=runtime_env,
                     log_to_driver=False)  # fmt: skip
            return True
        except Exception as exc:  # Ray raises a bare Exception for this time-out
            ray.shutdown()
            if "timed out during startup" not in str(exc) or attempt == LOCAL_START_ATTEMPTS - 1:
                raise
    return True


#: attempts at starting a local Ray instance (see :func:`init_ray`)
LOCAL_START_ATTEMPTS = 3


def train_rllib(
    env_id: str,
    timesteps: int,
    out: str | Path,
    hp: dict[str, Any],
    env_kwargs: dict[str, Any],
    n_envs: int,
    num_env_runners: int,
    address: str | None = None,
    seed: int = 0,
    eval_freq: int = 0,
    eval_episodes: int = 3,
    checkpoint_freq: int = 0,
    progress: bool = True,
) -> dict[str, Any]:
    """PPO on RLlib until ``timesteps`` env steps are sampled; returns the summary written to ``out/train.json``.

    ``hp`` is the YAML entry without ``policy`` / ``n_envs`` / ``n_timesteps`` /
    ``env_kwargs``; ``n_envs`` only sizes the train batch (``n_steps * n_envs``,
    as with SB3), so changing ``num_env_runners`` changes throughput, not the
    algorithm. ``eval_freq`` / ``checkpoint_freq`` are in env steps (0: none).
    """
    if num_env_runners < 0:
        raise ValueError(f"num_env_runners must be >= 0, got {num_env_runners}")
    policy_kwargs = dict(hp.get("policy_kwargs") or {})
    extractor = policy_kwargs.pop("features_extractor_class", None)
    if extractor not in (None, "point_set"):
        raise ValueError(f"the rllib backend supports features_extractor_class 'point_set' only, got {extractor!r}")
    model_config = {"net_arch": policy_kwargs.pop("net_arch", [64, 64]),
                    "features_extractor_kwargs": policy_kwargs.pop("features_extractor_kwargs", {})}  # fmt: skip
    if policy_kwargs:
        raise ValueError(f"policy_kwargs not supported by the rllib backend: {', '.join(sorted(policy_kwargs))}")
    settings = ppo_settings({k: v for k, v in hp.items() if k != "policy_kwargs"}, n_envs, timesteps)
    batch = settings["train_batch_size_per_learner"]
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    started = init_ray(address, num_env_runners)
    try:
        return _train_loop(env_id, timesteps, out, env_kwargs, settings, model_config, num_env_runners, address,
                           seed, max(0, eval_freq) // batch if eval_freq else 0, eval_episodes, checkpoint_freq,
                           progress, hp)  # fmt: skip
    finally:
        if started:
            import ray

            ray.shutdown()


def _train_loop(env_id, timesteps, out, env_kwargs, settings, model_config, num_env_runners, address, seed,
                eval_interval, eval_episodes, checkpoint_freq, progress, hp) -> dict[str, Any]:  # fmt: skip
    from torch.utils.tensorboard import SummaryWriter
    from tqdm.auto import tqdm

    config = build_config(env_id, env_kwargs, settings, model_config, num_env_runners, seed,
                          max(1, eval_interval) if eval_interval else 0, eval_episodes)  # fmt: skip
    algo = config.build_algo()
    writer = SummaryWriter(str(out / "tb"))
    bar = tqdm(total=timesteps, desc="train (rllib)", unit="step", disable=not progress)
    history: list[dict[str, Any]] = []
    steps, next_ckpt, t0 = 0, checkpoint_freq or 0, time.perf_counter()
    try:
        while steps < timesteps:
            t = time.perf_counter()
            rec = _iteration_record(algo.train(), time.perf_counter() - t)
            bar.update(rec["env_steps"] - steps)
            steps = rec["env_steps"]
            history.append(rec)
            for key in ("episode_return_mean", "episode_len_mean", "crash_rate", "eval_return_mean"):
                if rec[key] is not None:
                    writer.add_scalar(f"rollout/{key}", rec[key], steps)
            writer.add_scalar("time/steps_per_s", (rec["env_steps"] - (history[-2]["env_steps"] if len(history) > 1
                                                                      else 0)) / max(rec["wall_s"], 1e-9), steps)  # fmt: skip
            if checkpoint_freq and steps >= next_ckpt:
                algo.save_to_path(str((out / "checkpoints" / f"step_{steps}").resolve()))
                next_ckpt += checkpoint_freq
        wall = time.perf_counter() - t0
        algo.save_to_path(str((out / CHECKPOINT_DIR).resolve()))
    finally:
        bar.close()
        writer.close()
        algo.stop()
    summary = {
        "backend": "rllib",
        "algo": "ppo",
        "env_id": env_id,
        "env_kwargs": env_kwargs,
        "policy": "PointSetPPOModule",
        "timesteps": steps,
        "num_env_runners": num_env_runners,
        "address": address,
        "seed": seed,
        "wall_time_s": round(wall, 1),
        "steps_per_s": round(steps / wall, 2),
        "hyperparams": hp,
        "rllib_settings": {**settings, "model_config": model_config},
        "iterations": history,
        "recent_episodes": {k: history[-1][k] for k in ("episode_return_mean", "episode_len_mean", "crash_rate")},
        "model": str(out / CHECKPOINT_DIR),
    }
    text = json.dumps(summary, indent=2)
    (out / "train.json").write_text(text)
    (out / f"{CHECKPOINT_DIR}.json").write_text(text)
    return summary


def is_rllib_checkpoint(path: str | Path) -> bool:
    """A directory holding an RLlib algorithm checkpoint (or its RLModule)."""
    p = Path(path)
    return p.is_dir() and (p.joinpath(*MODULE_SUBDIR).is_dir() or (p / "class_and_ctor_args.pkl").exists())


class RLlibPolicy:
    """The RLModule of an RLlib checkpoint behind the ``predict(obs, deterministic)`` interface of SB3 models.

    Needs only torch and ray.rllib (no Ray cluster): the module is rebuilt from
    the checkpoint and run on one observation at a time; ``deterministic``
    takes the arg-max action, else samples the categorical distribution.
    """

    def __init__(self, path: str | Path):
        require_ray()
        from ray.rllib.core.rl_module.rl_module import RLModule

        p = Path(path)
        module_dir = p.joinpath(*MODULE_SUBDIR) if p.joinpath(*MODULE_SUBDIR).is_dir() else p
        self.module = RLModule.from_checkpoint(str(module_dir.resolve()))
        self.module.eval()
        self.observation_space = self.module.observation_space
        self.action_space = self.module.action_space

    def predict(self, obs, deterministic: bool = True):
        import torch

        def batch1(x):
            return torch.as_tensor(np.asarray(x))[None]

        o = {k: batch1(v) for k, v in obs.items()} if isinstance(obs, dict) else batch1(obs)
        with torch.no_grad():
            logits = self.module.forward_inference({"obs": o})["action_dist_inputs"][0]
        if deterministic:
            return int(torch.argmax(logits)), None
        return int(torch.distributions.Categorical(logits=logits).sample()), None
