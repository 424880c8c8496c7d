"""Ray RLlib backend for ``rhs-slam train --backend rllib`` (training beyond one machine).

PPO (``--algo ppo``) and the fine-tuning stage of :mod:`agents.algos.finetune` (``--algo finetune``) on
RLlib's new API stack (``EnvRunner`` actors sample, a ``Learner`` updates), from the same YAML
entries as the stable-baselines3 backend (``agents/hyperparams/ppo.yml`` / ``finetune.yml``):

* the env is registered with ``ray.tune.register_env(<gym id>, creator)``; the
  creator (:func:`make_env`) imports ``rhs_env`` (which registers the gym ids in each Ray worker),
  calls ``gym.make(<id>, **env_kwargs)`` and wraps the env as the SB3 backend does:
  :class:`agents.policies.privileged.PrivilegedObservation` when the critic is privileged, then
  :class:`agents.policies.decision.HoldAction` for a ``decision_interval`` k > 1 (``decision_mode``:
  ``hold`` or ``pulse``). ``env_config`` (:func:`env_config`) carries the kwargs and the
  wrappers, so a worker on another machine rebuilds exactly the same env;
* observations reach the policy unflattened: :class:`PointSetPPOModule` (a
  ``TorchRLModule`` with RLlib's ``ValueFunctionAPI``) encodes Dict observations
  with the masked point-set encoder of :mod:`agents.policies.features` (the one the
  stable-baselines3 backend uses, permutation invariant, padding ignored) and
  Box observations by flattening; separate policy and value MLPs (``net_arch``)
  sit on the shared encoding; with the privileged key in the observation the critic has its own
  encoder and reads the key too, the actor never does (an asymmetric actor-critic, as
  :class:`agents.algos.finetune.PrivilegedCriticPolicy`);
* the learner is :class:`AnchoredPPOLearner`: RLlib's PPO loss, plus for the fine-tune the
  decaying anchor ``lambda(t) KL(pi_student || pi)`` (:func:`agents.algos.finetune.anchor_coef`);
* hyperparameters map as:

  | YAML entry (stable-baselines3) | RLlib |
  |---|---|
  | ``n_steps * n_envs`` (decisions) | ``train_batch_size_per_learner`` |
  | ``batch_size`` / ``n_epochs`` | ``minibatch_size`` / ``num_epochs`` |
  | ``learning_rate`` (``lin_<lr>``) | ``lr`` (a linear schedule to 0 over the run's decisions) |
  | ``gamma`` / ``gae_lambda`` | ``gamma`` / ``lambda_`` |
  | ``clip_range`` | ``clip_param`` |
  | ``ent_coef`` / ``vf_coef`` / ``max_grad_norm`` | ``entropy_coeff`` / ``vf_loss_coeff`` / ``grad_clip`` |
  | (SB3 has neither) | ``use_kl_loss=False``, ``vf_clip_param=1e30`` (no clip) |
  | ``policy_kwargs`` | ``model_config``: ``net_arch``, ``features_extractor_kwargs`` (point-set only) |
  | ``decision_interval`` / ``decision_mode`` | the env creator's :class:`agents.policies.decision.HoldAction` |
  | ``privileged_critic`` | the creator's ``PrivilegedObservation`` and the module's critic |
  | ``anchor_coef`` / ``anchor_fraction`` | the learner's anchor (``learner_config_dict["finetune"]``) |
  | ``anchor_epochs`` | 0: no anchor; else the term is in every minibatch's loss |
  | ``critic_warmup_fraction`` | the actor's logits detached in the loss while it lasts (a shared encoder learns) |
  | ``correct_class_prior`` / ``prior_steps`` | the student corrected with SB3 before its actor is copied |
  | ``shield`` / ``reward_shaping`` | the creator's ``ShieldAction`` / ``RewardShaping`` |

  Two differences from the SB3 fine-tune: the anchor is a term of the PPO loss on each
  minibatch (RLlib's loss is one function) instead of ``anchor_epochs`` separate passes after
  the update, and ``t`` counts decisions sampled (RLlib's ``num_env_steps_sampled_lifetime``
  under a ``HoldAction``), which is the same fraction of the run;
* ``--algo finetune --init-policy STUDENT.zip`` loads the student with stable-baselines3,
  corrects its logits for its class weights (:func:`agents.algos.finetune.measure_prior`), copies its
  actor into the module (:func:`student_actor_state`: extractor -> ``encoder`` and the critic's
  ``vf_encoder``, policy MLP and action head -> ``pi``) and freezes that as the anchor's teacher;
  without ``--init-policy`` it is PPO from scratch with the privileged critic;
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
RLModule is what ``rhs-slam evaluate --policy DIR/rllib_checkpoint`` loads, held for the
decision interval as a zip is), ``rllib_checkpoint.json`` beside it and ``train.json`` (env id,
env kwargs, decision interval and mode, settings, timings, per-iteration progress with the
anchor's ``lambda`` and KL), ``checkpoints/step_<n>/`` every ``checkpoint_freq`` env steps,
``tb/`` (TensorBoard scalars per iteration). The fine-tune also writes ``model.zip`` /
``model.json``: the trained actor as a plain stable-baselines3 student
(:func:`export_module_actor`, what :func:`agents.algos.finetune.export_actor` writes), which
``rhs-slam evaluate`` / ``demo`` run without Ray.

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

from agents.policies.rllib_policy import (  # noqa: F401  (re-exported: the checkpoint side, importable without the trainer)
    CHECKPOINT_DIR,
    MODULE_SUBDIR,
    RLlibPolicy,
    is_rllib_checkpoint,
    require_ray,
)

__all__ = [
    "AnchoredPPOLearner", "CHECKPOINT_DIR", "CrashRateCallback", "LOCAL_START_ATTEMPTS", "PointSetPPOModule",
    "RLlibPolicy", "SB3_EXTRACTORS", "build_config", "env_config", "export_module_actor", "init_ray",
    "is_rllib_checkpoint", "make_env", "model_settings", "ppo_settings", "require_ray", "student_actor_state",
    "train_rllib",
]


def env_config(env_kwargs: dict[str, Any], decision_interval: int = 1, decision_mode: str = "hold",
               privileged: bool = False, shield: dict[str, Any] | None = None,
               shaping: dict[str, Any] | None = None) -> dict[str, Any]:
    """The ``env_config`` every Ray worker rebuilds its env from (:func:`make_env`): the ``gym.make`` kwargs and the
    wrappers, so a runner on another machine samples exactly the env the driver describes."""
    from agents.policies.decision import check_decision_interval, check_decision_mode

    return {"env_kwargs": dict(env_kwargs), "decision_interval": check_decision_interval(decision_interval),
            "decision_mode": check_decision_mode(decision_mode), "privileged": bool(privileged),
            "shield": None if shield is None else dict(shield), "shaping": None if shaping is None else dict(shaping)}


def make_env(env_id: str, config: dict[str, Any] | None = None) -> gym.Env:
    """The creator registered with ``ray.tune.register_env``: ``gym.make(env_id, **env_kwargs)``, then (``shield``)
    :class:`agents.policies.shield.ShieldAction`, (``privileged``) :class:`agents.policies.privileged.PrivilegedObservation`,
    (``shaping``) :class:`agents.algos.shaping.RewardShaping` and (``decision_interval`` k > 1)
    :class:`agents.policies.decision.HoldAction` with ``decision_mode``'s fill, in the order the SB3 backend wraps them."""
    import rhs_env  # noqa: F401  (registers the rhs ids in this worker)
    from agents.policies.decision import HoldAction, fill_action

    cfg = env_config(**{"env_kwargs": {}, **dict(config or {})})
    env = gym.make(env_id, **cfg["env_kwargs"])
    if cfg["shield"] is not None:
        from agents.policies.shield import ShieldAction

        env = ShieldAction(env, cfg["shield"])
    if cfg["privileged"]:
        from agents.policies.privileged import PrivilegedObservation

        env = PrivilegedObservation(env)
    if cfg["shaping"] is not None:
        from agents.algos.shaping import RewardShaping

        env = RewardShaping(env, cfg["shaping"])
    if cfg["decision_interval"] > 1:
        env = HoldAction(env, cfg["decision_interval"], fill_action(cfg["decision_mode"]))
    return env


def _encoder(observation_space: gym.spaces.Space, model_config: dict[str, Any]):
    """Masked point-set encoder for Dict observations, flatten for Box ones; returns (module, width)."""
    from torch import nn

    from agents.policies.features import PointSetExtractor

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
    import torch
    from ray.rllib.core.columns import Columns
    from ray.rllib.core.rl_module.apis import ValueFunctionAPI
    from ray.rllib.core.rl_module.torch import TorchRLModule
except ImportError:  # pragma: no cover  (base install)
    TorchRLModule = None

if TorchRLModule is not None:

    class PointSetPPOModule(TorchRLModule, ValueFunctionAPI):
        """Encoder (point-set or flatten) -> policy MLP (logits); value MLP on the critic's features.

        ``model_config``: ``net_arch`` (hidden widths of both heads, default [64, 64]),
        ``features_extractor_kwargs`` (``point_dim``, ``box_dim`` of the point-set encoder).
        Output gains follow SB3's PPO: 0.01 for the logits, 1 for the value.

        Without :data:`agents.policies.privileged.PRIVILEGED_KEY` in the observation space the value MLP
        shares the actor's encoding (SB3's ``MultiInputPolicy``). With it (the env wrapped in
        :class:`agents.policies.privileged.PrivilegedObservation`): an asymmetric actor-critic as
        :class:`agents.algos.finetune.PrivilegedCriticPolicy`. The actor's encoder reads the observation
        without the key; the critic has its own encoder and ``relu(W [enc(o); p] + b)``
        (:class:`agents.algos.finetune.CriticFeatures`) before its MLP, so the logits never depend on ``p``.
        """

        def setup(self):
            from torch import nn

            from agents.policies.privileged import PRIVILEGED_KEY, without_privileged

            cfg = dict(self.model_config or {})
            hidden = list(cfg.get("net_arch") or [64, 64])
            space = self.observation_space
            self.privileged = isinstance(space, gym.spaces.Dict) and PRIVILEGED_KEY in space.spaces
            actor_space = without_privileged(space) if self.privileged else space
            self.encoder, width = _encoder(actor_space, cfg)
            self.pi = _mlp(width, hidden, int(self.action_space.n), 0.01)
            if self.privileged:
                self.vf_encoder, _ = _encoder(actor_space, cfg)
                dim = int(np.prod(space[PRIVILEGED_KEY].shape or (1,)))
                self.vf_fuse = nn.Sequential(nn.Linear(width + dim, width), nn.ReLU())
            self.vf = _mlp(width, hidden, 1, 1.0)

        @staticmethod
        def _actor_obs(obs):
            from agents.policies.privileged import PRIVILEGED_KEY

            return {k: v.float() for k, v in obs.items() if k != PRIVILEGED_KEY}

        def _encode(self, batch):
            obs = batch[Columns.OBS]
            if isinstance(obs, dict):
                return self.encoder(self._actor_obs(obs))
            return self.encoder(obs.float())

        def _critic_features(self, batch):
            """What the value MLP reads: the actor's encoding, or (privileged) the critic's fused one."""
            from agents.policies.privileged import PRIVILEGED_KEY

            if not self.privileged:
                return self._encode(batch)
            obs = batch[Columns.OBS]
            h = self.vf_encoder(self._actor_obs(obs))
            return self.vf_fuse(torch.cat([h, obs[PRIVILEGED_KEY].float()], dim=1))

        def actor_logits(self, obs):
            """The action logits of an observation batch (a dict of tensors or a tensor); never reads the key."""
            return self.pi(self._encode({Columns.OBS: obs}))

        def _forward(self, batch, **kwargs):
            return {Columns.ACTION_DIST_INPUTS: self.pi(self._encode(batch))}

        def _forward_train(self, batch, **kwargs):
            emb = self._encode(batch)
            critic = self._critic_features(batch) if self.privileged else emb
            return {Columns.ACTION_DIST_INPUTS: self.pi(emb), Columns.EMBEDDINGS: critic}

        def compute_values(self, batch, embeddings=None):
            if embeddings is None:
                embeddings = self._critic_features(batch)
            return self.vf(embeddings).squeeze(-1)

        def load_actor_state(self, state: dict[str, Any]) -> None:
            """Copy ``state`` (this module's own key names, :func:`student_actor_state`) into the module."""
            own = self.state_dict()
            wrong = [k for k, v in state.items() if k not in own or tuple(own[k].shape) != tuple(v.shape)]
            if wrong:
                raise ValueError("init_policy: the student's network differs from the YAML's policy_kwargs "
                                 f"({wrong[:3]} ...)")
            self.load_state_dict({k: torch.as_tensor(v) for k, v in state.items()}, strict=False)


#: a stable-baselines3 actor-critic's encoder prefixes (shared or not, they hold the same extractor in a student)
SB3_EXTRACTORS = ("features_extractor.", "pi_features_extractor.")


def student_actor_state(student_policy: Any, n_hidden: int, privileged: bool) -> dict[str, Any]:
    """A stable-baselines3 student's actor as :class:`PointSetPPOModule` state: the point-set extractor -> ``encoder``
    (and, ``privileged``, the critic's ``vf_encoder``, as :func:`agents.algos.finetune.load_actor` starts the critic),
    ``mlp_extractor.policy_net.<i>`` -> ``pi.<i>``, ``action_net`` -> ``pi.<2 n_hidden>`` (the logits layer)."""
    out: dict[str, Any] = {}
    for key, value in student_policy.state_dict().items():
        if key.startswith("features_extractor."):
            rest = key[len("features_extractor."):]
            out["encoder." + rest] = value.detach().clone()
            if privileged:
                out["vf_encoder." + rest] = value.detach().clone()
        elif key.startswith("mlp_extractor.policy_net."):
            out["pi." + key[len("mlp_extractor.policy_net."):]] = value.detach().clone()
        elif key.startswith("action_net."):
            out[f"pi.{2 * n_hidden}." + key[len("action_net."):]] = value.detach().clone()
    return out


def export_module_actor(module: Any, student_policy: Any) -> None:
    """The inverse of :func:`student_actor_state`: ``module``'s actor into a stable-baselines3 policy of the same
    ``net_arch`` (its extractor, policy MLP and action head; its value head too where the module's critic
    shares the actor's encoder, since then it is SB3's own layout)."""
    n_hidden = (len(module.pi) - 1) // 2
    state = module.state_dict()
    target = student_policy.state_dict()
    out: dict[str, Any] = {}
    for key, value in state.items():
        part, _, rest = key.partition(".")
        if part == "encoder":
            out.update({p + rest: value for p in SB3_EXTRACTORS if p + rest in target})
        elif part == "pi":
            layer, _, leaf = rest.partition(".")
            out[f"action_net.{leaf}" if int(layer) == 2 * n_hidden else f"mlp_extractor.policy_net.{rest}"] = value
        elif part == "vf" and not module.privileged:
            layer, _, leaf = rest.partition(".")
            out[f"value_net.{leaf}" if int(layer) == 2 * n_hidden else f"mlp_extractor.value_net.{rest}"] = value
    wrong = [k for k, v in out.items() if k not in target or tuple(target[k].shape) != tuple(v.shape)]
    if wrong:
        raise ValueError(f"export: the RLModule's actor does not fit the stable-baselines3 policy ({wrong[:3]} ...)")
    student_policy.load_state_dict(out, strict=False)


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
        # stable-baselines3's PPO has neither RLlib's adaptive KL penalty nor its clip of the value loss
        "use_kl_loss": False,
        "vf_clip_param": 1e30,  # no clip
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


if TorchRLModule is not None:
    import copy

    from ray.rllib.algorithms.ppo.torch.ppo_torch_learner import PPOTorchLearner
    from ray.rllib.core import DEFAULT_MODULE_ID
    from ray.rllib.utils.metrics import NUM_ENV_STEPS_SAMPLED_LIFETIME

    class AnchoredPPOLearner(PPOTorchLearner):
        """RLlib's PPO loss plus the decaying anchor of :mod:`agents.algos.finetune`, on every minibatch:

            L = L_PPO + lambda(t) * mean_o KL( pi_teacher(.|o) || pi_theta(.|o) ),

        ``lambda(t)`` = :func:`agents.algos.finetune.anchor_coef` at ``t / T``, ``t`` the decisions sampled so far (RLlib's
        ``num_env_steps_sampled_lifetime``, counted before each update, as stable-baselines3 counts them) and ``T``
        the run's (``learner_config_dict["anchor_total_steps"]``); the other fields of the
        :class:`agents.algos.finetune.FinetuneConfig` come in ``learner_config_dict["finetune"]``. The teacher is a frozen
        copy of the module as :meth:`start_from` leaves it (the student's actor); without one it is plain PPO.
        Logs ``anchor_coef`` (with a teacher) and ``anchor_kl`` (while ``lambda > 0``) per module. During the
        critic warm-up (``critic_warmup_fraction``) the loss sees the actor's logits detached, so only the critic
        learns (``critic_warmup`` logged 1).
        """

        teacher: Any = None
        progress: float = 0.0

        def start_from(self, actor_state: dict[str, Any] | None, anchor: bool) -> bool:
            """Load ``actor_state`` into the module (None: keep it) and, ``anchor``, freeze a copy as the teacher."""
            module: Any = self.module[DEFAULT_MODULE_ID].unwrapped()
            if actor_state is not None:
                module.load_actor_state(actor_state)
            if anchor:
                teacher = copy.deepcopy(module).eval()
                for param in teacher.parameters():
                    param.requires_grad_(False)
                self.teacher = teacher
            return True

        def before_gradient_based_update(self, *, timesteps: dict[str, Any]) -> None:
            super().before_gradient_based_update(timesteps=timesteps)
            total = float(self.config.learner_config_dict.get("anchor_total_steps") or 1)
            self.progress = min(1.0, float(timesteps.get(NUM_ENV_STEPS_SAMPLED_LIFETIME, 0)) / total)

        def finetune_config(self) -> Any:
            """The :class:`agents.algos.finetune.FinetuneConfig` of ``learner_config_dict["finetune"]``; None for plain PPO."""
            from agents.algos.finetune import FinetuneConfig

            fields = self.config.learner_config_dict.get("finetune")
            return FinetuneConfig(**fields) if fields else None

        def anchor_coef(self) -> float:
            from agents.algos.finetune import anchor_coef

            config = self.finetune_config()
            if self.teacher is None or config is None or config.anchor_epochs == 0:
                return 0.0
            return anchor_coef(config, self.progress)

        def critic_warming(self) -> bool:
            """Whether this update trains the critic alone (:func:`agents.algos.finetune.critic_warming`)."""
            from agents.algos.finetune import critic_warming

            config = self.finetune_config()
            return config is not None and critic_warming(config, self.progress)

        def compute_loss_for_module(self, *, module_id, config, batch, fwd_out):
            warming = self.critic_warming()
            if warming:  # the actor's logits without their graph: the loss reaches the critic only
                fwd_out = {**fwd_out, Columns.ACTION_DIST_INPUTS: fwd_out[Columns.ACTION_DIST_INPUTS].detach()}
            self.metrics.log_value((module_id, "critic_warmup"), float(warming), window=1)
            loss = super().compute_loss_for_module(module_id=module_id, config=config, batch=batch, fwd_out=fwd_out)
            if self.teacher is None or warming:
                return loss
            coef = self.anchor_coef()
            self.metrics.log_value((module_id, "anchor_coef"), coef, window=1)
            if coef <= 0:
                return loss
            with torch.no_grad():
                target = torch.log_softmax(self.teacher.actor_logits(batch[Columns.OBS]), dim=-1)
            current = torch.log_softmax(fwd_out[Columns.ACTION_DIST_INPUTS], dim=-1)
            kl = (target.exp() * (target - current)).sum(-1)
            if Columns.LOSS_MASK in batch:
                mask = batch[Columns.LOSS_MASK]
                kl_mean = kl[mask].sum() / mask.sum().clamp(min=1)
            else:
                kl_mean = kl.mean()
            self.metrics.log_value((module_id, "anchor_kl"), float(kl_mean.detach()), window=1)
            return loss + coef * kl_mean


def build_config(
    env_id: str,
    env_cfg: dict[str, Any],
    settings: dict[str, Any],
    model_config: dict[str, Any],
    num_env_runners: int,
    seed: int,
    eval_interval: int = 0,
    eval_episodes: int = 3,
    learner_config: dict[str, Any] | None = None,
):
    """The ``PPOConfig``: env registered by its gym id and rebuilt from ``env_cfg`` (:func:`env_config`), the
    point-set RLModule, one local :class:`AnchoredPPOLearner` (plain PPO unless ``learner_config`` sets the anchor)."""
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.core.rl_module.rl_module import RLModuleSpec
    from ray.tune.registry import register_env

    register_env(env_id, lambda cfg, _id=env_id: make_env(_id, dict(cfg)))
    config = (
        PPOConfig()
        .environment(env=env_id, env_config=dict(env_cfg))
        .framework("torch")
        .env_runners(
            num_env_runners=int(num_env_runners),
            num_envs_per_env_runner=1,
            num_cpus_per_env_runner=1,
            rollout_fragment_length="auto",
            sample_timeout_s=3600.0,
        )
        .learners(num_learners=0, learner_class=AnchoredPPOLearner, learner_config_dict=dict(learner_config or {}))
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


def _iteration_record(result: dict[str, Any], wall: float, k: int = 1) -> dict[str, Any]:
    """Steps, episode return / length / crash rate (recent episodes) and timing of one ``algo.train()``.

    RLlib counts agent decisions; with a decision interval ``k`` the env steps are ``decisions * k`` (an
    episode cut short by a crash takes fewer, as in the SB3 backend's count); episode lengths are in decisions.
    """
    er = result.get("env_runners") or {}
    steps = result.get("num_env_steps_sampled_lifetime", er.get("num_env_steps_sampled_lifetime"))
    ev = (result.get("evaluation") or {}).get("env_runners") or {}

    def num(x):
        return None if x is None or not np.isfinite(float(x)) else float(x)

    return {
        "iteration": int(result.get("training_iteration", 0)),
        "env_steps": int(steps or 0) * int(k),
        "decisions": int(steps or 0),
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


def model_settings(policy_kwargs: dict[str, Any]) -> dict[str, Any]:
    """A YAML entry's ``policy_kwargs`` (extractor by name, :func:`agents.algos.hyperparams.policy_kwargs_by_name`) as the
    RLModule's ``model_config``; ``ValueError`` for what the RLlib backend does not build."""
    policy_kwargs = dict(policy_kwargs or {})
    extractor = policy_kwargs.pop("features_extractor_class", None)
    if extractor not in (None, "point_set"):
        raise ValueError(f"the rllib backend supports features_extractor_class 'point_set' only, got {extractor!r}")
    model_config = {"net_arch": list(policy_kwargs.pop("net_arch", [64, 64])),
                    "features_extractor_kwargs": dict(policy_kwargs.pop("features_extractor_kwargs", {}))}  # fmt: skip
    if policy_kwargs:
        raise ValueError(f"policy_kwargs not supported by the rllib backend: {', '.join(sorted(policy_kwargs))}")
    return model_config


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
    decision_interval: int = 1,
    decision_mode: str = "hold",
    algo: str = "ppo",
    init_policy: str | Path | None = None,
    policy: str = "MultiInputPolicy",
) -> dict[str, Any]:
    """PPO on RLlib until ``timesteps`` env steps are sampled; returns the summary written to ``out/train.json``.

    ``hp`` is the YAML entry without ``policy`` / ``n_envs`` / ``n_timesteps`` / ``env_kwargs`` /
    ``decision_*``; ``n_envs`` only sizes the train batch (``n_steps * n_envs`` decisions,
    as with SB3), so changing ``num_env_runners`` changes throughput, not the
    algorithm. ``eval_freq`` / ``checkpoint_freq`` are in env steps (0: none). With ``decision_interval``
    k > 1 every worker's env is wrapped in :class:`agents.policies.decision.HoldAction` (``decision_mode``) and the run
    takes ``ceil(timesteps / k)`` decisions. ``algo="finetune"``: the fine-tuning stage of
    :mod:`agents.algos.finetune` from ``hp``'s :class:`agents.algos.finetune.FinetuneConfig` fields (:func:`_finetune_start`);
    it also writes ``out/model.zip`` / ``model.json``, the trained actor as a plain stable-baselines3 student
    (:func:`export_module_actor`; ``policy`` is its SB3 policy class name).
    """
    from agents.policies.decision import check_decision_interval, check_decision_mode

    if num_env_runners < 0:
        raise ValueError(f"num_env_runners must be >= 0, got {num_env_runners}")
    if algo not in ("ppo", "finetune"):
        raise ValueError(f"the rllib backend trains ppo or finetune, got {algo!r}")
    k = check_decision_interval(decision_interval)
    mode = check_decision_mode(decision_mode)
    model_config = model_settings(hp.get("policy_kwargs") or {})
    ppo_hp = {key: v for key, v in hp.items() if key not in ("policy_kwargs", "shield", "reward_shaping")}
    shield, shaping = _wrapper_settings(hp)
    finetune = None
    if algo == "finetune":
        from agents.algos.finetune import FINETUNE_KEYS, FinetuneConfig
        from rhs_common.validation import build

        finetune = build(FinetuneConfig, {key: v for key, v in ppo_hp.items() if key in FINETUNE_KEYS}, "finetune")
        ppo_hp = {key: v for key, v in ppo_hp.items() if key not in FINETUNE_KEYS}
    decisions = -(-int(timesteps) // k)
    settings = ppo_settings(ppo_hp, n_envs, decisions)
    batch = settings["train_batch_size_per_learner"]
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    start = _finetune_start(env_id, env_kwargs, finetune, init_policy, k, mode, seed, model_config, policy) \
        if finetune is not None else None
    privileged = bool(finetune is not None and finetune.privileged_critic)
    run = {"env_id": env_id, "timesteps": timesteps, "decisions": decisions, "k": k, "mode": mode,
           "env_cfg": env_config(env_kwargs, k, mode, privileged, shield, shaping), "settings": settings,
           "model_config": model_config, "num_env_runners": num_env_runners, "address": address, "seed": seed,
           "eval_interval": max(0, eval_freq) // (batch * k) if eval_freq else 0, "eval_episodes": eval_episodes,
           "checkpoint_freq": checkpoint_freq, "progress": progress, "hp": hp, "algo": algo, "finetune": finetune,
           "start": start, "policy": policy}  # fmt: skip
    started = init_ray(address, num_env_runners)
    try:
        return _train_loop(out, env_kwargs, run)
    finally:
        if started:
            import ray

            ray.shutdown()


def _wrapper_settings(hp: dict[str, Any]) -> tuple[dict[str, Any] | None, dict[str, Any] | None]:
    """The YAML entry's ``shield`` and ``reward_shaping`` as full, validated records (None where absent)."""
    from dataclasses import asdict

    from agents.algos.shaping import ShapingConfig
    from agents.policies.shield import shield_record
    from rhs_common.validation import build

    shield = shield_record(hp.get("shield"))
    shaping = None if hp.get("reward_shaping") is None else asdict(
        build(ShapingConfig, hp["reward_shaping"], "reward_shaping"))
    return shield, shaping


def _finetune_start(env_id: str, env_kwargs: dict[str, Any], config: Any, init_policy: str | Path | None, k: int,
                    mode: str, seed: int, model_config: dict[str, Any], policy: str) -> dict[str, Any]:
    """The start of the fine-tune: the student zip ``init_policy`` loaded with stable-baselines3, its logits
    corrected for its class weights (:func:`agents.algos.finetune.measure_prior`, as the SB3 backend does), its actor
    as module state (:func:`student_actor_state`); without ``init_policy`` a fresh SB3 policy of the YAML (what
    the trained actor is exported into). Returns the student model, the state (or None) and the record."""
    from types import SimpleNamespace

    from stable_baselines3 import PPO

    from agents.evaluate import policy_metadata

    n_hidden = len(model_config["net_arch"])
    if init_policy is None:
        return {"student": _plain_student(env_id, env_kwargs, model_config, policy), "state": None, "record": {}}
    if not Path(init_policy).exists():
        raise FileNotFoundError(f"--init-policy: no such student zip: {init_policy}")
    student = PPO.load(init_policy, device="cpu")
    record: dict[str, Any] = {"init_policy": str(init_policy)}
    if config.correct_class_prior:
        from agents.algos.finetune import measure_prior

        dagger = policy_metadata(init_policy).get("dagger") or {}
        power = float(dagger.get("class_weight_power", 0.0))
        record["class_prior"] = measure_prior(env_id, env_kwargs, student, SimpleNamespace(decision_interval=k,
                                              decision_mode=mode), config, power,
                                              bool(dagger.get("label_between", False)), seed + 20_000)  # fmt: skip
    state = student_actor_state(student.policy, n_hidden, config.privileged_critic)
    return {"student": student, "state": state, "record": record}


def _plain_student(env_id: str, env_kwargs: dict[str, Any], model_config: dict[str, Any], policy: str) -> Any:
    """A fresh stable-baselines3 PPO of the YAML's network on the plain env (what a from-scratch actor goes into)."""
    from stable_baselines3 import PPO

    from agents.evaluate import make_env
    from agents.policies.features import FEATURE_EXTRACTORS

    env = make_env(env_id, env_kwargs)
    kwargs: dict[str, Any] = {"net_arch": list(model_config["net_arch"])}
    if isinstance(env.observation_space, gym.spaces.Dict):
        kwargs.update(features_extractor_class=FEATURE_EXTRACTORS["point_set"],
                      features_extractor_kwargs=dict(model_config["features_extractor_kwargs"]))  # fmt: skip
    try:
        return PPO(policy, env, device="cpu", policy_kwargs=kwargs)
    finally:
        env.close()


def _start_learner(algo: Any, start: dict[str, Any] | None, anchor: bool) -> None:
    """Load the student's actor into the learner's module (and freeze the teacher), then send it to the runners."""
    if start is None or (start["state"] is None and not anchor):
        return
    state = start["state"]
    algo.learner_group.foreach_learner(lambda learner: learner.start_from(state, anchor))
    algo.env_runner_group.sync_weights(from_worker_or_learner_group=algo.learner_group, inference_only=True)
    if getattr(algo, "eval_env_runner_group", None) is not None:
        algo.eval_env_runner_group.sync_weights(from_worker_or_learner_group=algo.learner_group, inference_only=True)


def _train_loop(out: Path, env_kwargs: dict[str, Any], run: dict[str, Any]) -> dict[str, Any]:
    from torch.utils.tensorboard import SummaryWriter
    from tqdm.auto import tqdm

    k, settings, finetune, start = run["k"], run["settings"], run["finetune"], run["start"]
    anchor = bool(finetune is not None and start is not None and start["state"] is not None
                  and finetune.anchor_coef > 0 and finetune.anchor_epochs > 0)
    learner_config = {"anchor_total_steps": run["decisions"]}
    if anchor:
        from dataclasses import asdict

        learner_config["finetune"] = asdict(finetune)
    config = build_config(run["env_id"], run["env_cfg"], settings, run["model_config"], run["num_env_runners"],
                          run["seed"], max(1, run["eval_interval"]) if run["eval_interval"] else 0,
                          run["eval_episodes"], learner_config)  # fmt: skip
    algo = config.build_algo()
    _start_learner(algo, start, anchor)
    timesteps, checkpoint_freq = run["timesteps"], run["checkpoint_freq"]
    writer = SummaryWriter(str(out / "tb"))
    bar = tqdm(total=timesteps, desc=f"train (rllib {run['algo']})", unit="step", disable=not run["progress"])
    history: list[dict[str, Any]] = []
    steps, next_ckpt, t0 = 0, checkpoint_freq or 0, time.perf_counter()
    try:
        while steps < run["decisions"] * k:
            t = time.perf_counter()
            result = algo.train()
            rec = _iteration_record(result, time.perf_counter() - t, k)
            learner = (result.get("learners") or {}).get("default_policy") or {}
            if "anchor_coef" in learner:
                rec["anchor_coef"] = float(learner["anchor_coef"])
                rec["anchor_kl"] = float(learner["anchor_kl"]) if "anchor_kl" in learner else None
            bar.update(rec["env_steps"] - steps)
            steps = rec["env_steps"]
            history.append(rec)
            for key in ("episode_return_mean", "episode_len_mean", "crash_rate", "eval_return_mean", "anchor_coef",
                        "anchor_kl"):  # fmt: skip
                if rec.get(key) is not None:
                    writer.add_scalar(f"{'anchor' if key.startswith('anchor') else 'rollout'}/{key}", rec[key], steps)
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
    summary = _summary(out, env_kwargs, run, steps, wall, history, anchor)
    text = json.dumps(summary, indent=2)
    (out / "train.json").write_text(text)
    (out / f"{CHECKPOINT_DIR}.json").write_text(text)
    if finetune is not None and start is not None:
        _export_student(out, summary, start["student"], run["policy"])
    return summary


def _summary(out: Path, env_kwargs: dict[str, Any], run: dict[str, Any], steps: int, wall: float,
             history: list[dict[str, Any]], anchor: bool) -> dict[str, Any]:
    """The run's record (``train.json``): env, decision interval, settings, timings, per-iteration progress."""
    k, settings, finetune, start = run["k"], run["settings"], run["finetune"], run["start"]
    summary = {
        "backend": "rllib",
        "algo": run["algo"],
        "env_id": run["env_id"],
        "env_kwargs": env_kwargs,
        "policy": "PointSetPPOModule",
        "timesteps": steps,
        "decision_interval": k,
        "decision_mode": run["mode"],
        "decisions": steps // k,
        "num_env_runners": run["num_env_runners"],
        "address": run["address"],
        "seed": run["seed"],
        "wall_time_s": round(wall, 1),
        "steps_per_s": round(steps / wall, 2),
        "hyperparams": run["hp"],
        "rllib_settings": {**settings, "model_config": run["model_config"]},
        "iterations": history,
        "recent_episodes": {key: history[-1][key] for key in ("episode_return_mean", "episode_len_mean", "crash_rate")},
        "model": str(out / CHECKPOINT_DIR),
    }
    summary["shield"], summary["reward_shaping"] = run["env_cfg"]["shield"], run["env_cfg"]["shaping"]
    if finetune is not None:
        from dataclasses import asdict

        summary["finetune"] = {**asdict(finetune), "anchor": anchor}
        summary.update(start["record"] if start is not None else {})
    return summary


def _export_student(out: Path, summary: dict[str, Any], student: Any, policy: str) -> None:
    """``out/model.zip``: the trained RLModule's actor in ``student`` (a stable-baselines3 PPO), saved with its
    ``model.json`` (env, decision interval and mode, the run), so ``rhs-slam evaluate`` / ``demo`` run it
    without Ray."""
    module = RLlibPolicy(out / CHECKPOINT_DIR).module
    export_module_actor(module, student.policy)
    student.save(out / "model.zip")
    record = {**summary, "policy": policy, "model": str(out / "model.zip"),
              "rllib_checkpoint": str(out / CHECKPOINT_DIR)}  # fmt: skip
    (out / "model.json").write_text(json.dumps(record, indent=2))
