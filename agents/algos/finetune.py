"""Reinforcement learning on top of imitation: PPO fine-tuning of a DAgger student (``rhs-slam train --algo finetune``).

The student of :mod:`agents.algos.imitation` has reached its teacher (it scores what the
headway expert scores), so imitation can give no more. This stage goes on with PPO
(Schulman et al., 2017) from the student's weights, with three additions:

**An asymmetric actor-critic.** The actor sees only the env's observation; the
critic also reads the simulator's state (:mod:`agents.policies.privileged`: true gaps,
relative speeds, time left, the expert's action), added to the observation under
``"privileged"`` by :class:`agents.policies.privileged.PrivilegedObservation`.
:class:`PrivilegedCriticPolicy` is stable-baselines3's actor-critic with two
feature extractors: the actor's drops the key, the critic's appends the vector to
the same point-set features. Only the actor is kept: :func:`export_actor` writes it
into a copy of the student's zip, which runs on the plain env like any student.

**A decaying anchor.** After each PPO update, ``anchor_epochs`` passes over the
rollout's observations minimise

    lambda(t) * KL( pi_student(.|o) || pi_theta(.|o) ),
    lambda(t) = anchor_coef * max(0, 1 - t / (anchor_fraction * T)),

with ``t`` the env steps so far of ``T``: the policy starts near the student and is
pulled back towards it early, when the critic is still untrained; from
``anchor_fraction * T`` on the training is pure PPO (:class:`AnchoredPPO`).
``anchor_coef: 0`` is the control without the anchor.

**A critic warm-up.** The privileged critic starts untrained, so the first advantages
``A = sum_l (gamma lambda)^l delta_l`` are noise and the first policy-gradient steps
move the student at random. For the first ``critic_warmup_fraction * T`` env steps only
the critic learns (the actor's parameters take no gradient, :func:`critic_warming`); the
actor then starts from the student with a critic that has seen ``critic_warmup_fraction * T``
env steps of its returns (the usual value pre-training of fine-tuning from imitation).

**The student's logits corrected for its class weights.** DAgger fits the student by
weighted maximum likelihood with ``w_a = (n / (K n_a)) ** p`` (:func:`agents.algos.imitation.class_weights`);
its softmax is then ``pi_w(a|o) ~ w_a pi(a|o)``, biased towards the rare actions. The
correction subtracts ``log w_a`` from the action logits (the action head's bias), so
the start and the anchor are the expert's own action distribution as the student learned
it. ``n_a`` is measured: the expert's labels on ``prior_steps`` env steps that the
student drives (:func:`label_frequencies`), as in the student's last DAgger rounds.

Decisions are taken at 1 Hz in ``"pulse"`` mode (:mod:`agents.policies.decision`), the student's
own rate, so ``gamma`` is per second. Hyperparameters: ``agents/hyperparams/finetune.yml``
(PPO's arguments plus the fields of :class:`FinetuneConfig`). Without ``--init-policy``
the same stage is PPO from scratch with the privileged critic (no anchor, no correction). A
``reward_shaping`` entry (``{ttc_s, weight}``, :mod:`agents.algos.shaping`) adds a time-to-collision penalty to the
training reward; evaluation keeps highway-env's. A ``shield`` entry (:class:`agents.policies.shield.ShieldConfig` fields,
``{}`` for the defaults) trains under the radar safety shield (:class:`agents.policies.shield.ShieldAction` at every env
step, so PPO learns what the shield lets through) and saves it beside the model: ``rhs-slam evaluate`` and the
demo then drive the policy through the same shield.
"""

from __future__ import annotations

import copy
import sys
import time
from dataclasses import asdict, dataclass, fields
from functools import partial
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.policies import ActorCriticPolicy, MultiInputActorCriticPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

from agents.policies.privileged import PRIVILEGED_KEY, PrivilegedObservation, without_privileged
from rhs_common.validation import build, check_bool, check_int, check_range, check_types


@dataclass(frozen=True)
class FinetuneConfig:
    """The fine-tuning stage's own settings (the rest of a ``finetune.yml`` entry is PPO's)."""

    anchor_coef: float = 1.0  # lambda_0 of the KL pull towards the student (0: no anchor)
    anchor_fraction: float = 0.5  # the anchor decays linearly to 0 over this fraction of the run
    anchor_epochs: int = 1  # passes over the rollout per update that minimise the anchor term
    correct_class_prior: bool = True  # subtract log w_a from the student's action logits before starting
    prior_steps: int = 2000  # env steps the student drives to measure the expert's label frequencies n_a
    privileged_critic: bool = True  # the critic also reads agents.policies.privileged's ground truth
    critic_warmup_fraction: float = 0.0  # only the critic learns over this fraction of the run (1: never the actor)

    def __post_init__(self) -> None:
        check_types(self)
        check_range("anchor_coef", self.anchor_coef, 0.0, 1e3)
        check_range("anchor_fraction", self.anchor_fraction, 0.0, 1.0, low_open=True)
        check_int("anchor_epochs", self.anchor_epochs, 0, 100)
        check_bool("correct_class_prior", self.correct_class_prior)
        check_int("prior_steps", self.prior_steps, 1, 10**7)
        check_bool("privileged_critic", self.privileged_critic)
        check_range("critic_warmup_fraction", self.critic_warmup_fraction, 0.0, 1.0)


FINETUNE_KEYS = tuple(f.name for f in fields(FinetuneConfig))


class ActorFeatures(BaseFeaturesExtractor):
    """The actor's extractor: ``inner`` on the observation without :data:`agents.policies.privileged.PRIVILEGED_KEY`."""

    def __init__(self, observation_space: gym.spaces.Dict, inner: BaseFeaturesExtractor):
        super().__init__(observation_space, features_dim=inner.features_dim)
        self.inner = inner

    def forward(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        return self.inner({k: v for k, v in obs.items() if k != PRIVILEGED_KEY})


class CriticFeatures(BaseFeaturesExtractor):
    """The critic's extractor: ``relu(W [inner(o); p] + b)``, the point-set features and the privileged vector p.

    The output has ``inner``'s width, so stable-baselines3's value MLP takes it as it would the actor's features.
    """

    def __init__(self, observation_space: gym.spaces.Dict, inner: BaseFeaturesExtractor, privileged_dim: int):
        super().__init__(observation_space, features_dim=inner.features_dim)
        self.inner = inner
        self.fuse = nn.Sequential(nn.Linear(inner.features_dim + privileged_dim, inner.features_dim), nn.ReLU())

    def forward(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        h = self.inner({k: v for k, v in obs.items() if k != PRIVILEGED_KEY})
        return self.fuse(torch.cat([h, obs[PRIVILEGED_KEY].float()], dim=1))


class PrivilegedCriticPolicy(MultiInputActorCriticPolicy):
    """An actor-critic whose actor ignores ``obs["privileged"]`` and whose critic reads it (separate extractors).

    The observation space must hold :data:`agents.policies.privileged.PRIVILEGED_KEY`
    (:class:`agents.policies.privileged.PrivilegedObservation`); ``features_extractor_class`` /
    ``features_extractor_kwargs`` build the point-set part of both extractors.
    """

    def __init__(self, observation_space: gym.spaces.Dict, *args: Any, **kwargs: Any):
        if PRIVILEGED_KEY not in observation_space.spaces:
            raise ValueError(f"PrivilegedCriticPolicy needs the {PRIVILEGED_KEY!r} key in the observation "
                             "(wrap the env in agents.policies.privileged.PrivilegedObservation)")
        kwargs["share_features_extractor"] = False
        super().__init__(observation_space, *args, **kwargs)

    def make_features_extractor(self) -> BaseFeaturesExtractor:
        """First call: the actor's extractor; second call (stable-baselines3 builds the critic's next): the critic's."""
        space = self.observation_space
        assert isinstance(space, gym.spaces.Dict)
        inner = self.features_extractor_class(without_privileged(space), **self.features_extractor_kwargs)
        if getattr(self, "features_extractor", None) is None:
            return ActorFeatures(space, inner)
        return CriticFeatures(space, inner, int(np.prod(space[PRIVILEGED_KEY].shape or (1,))))


#: the actor's modules: a plain student's state-dict prefix -> the fine-tune policy's
ACTOR_PREFIXES = {
    "features_extractor.": ("features_extractor.inner.", "pi_features_extractor.inner."),
    "pi_features_extractor.": ("pi_features_extractor.inner.",),
    "mlp_extractor.policy_net.": ("mlp_extractor.policy_net.",),
    "action_net.": ("action_net.",),
}


def _renamed(state: dict[str, torch.Tensor], prefixes: dict[str, tuple[str, ...]]) -> dict[str, torch.Tensor]:
    out: dict[str, torch.Tensor] = {}
    for key, value in state.items():
        for old, news in prefixes.items():
            if key.startswith(old):
                out.update({new + key[len(old):]: value for new in news})
    return out


def load_actor(policy: Any, student: ActorCriticPolicy) -> None:
    """Copy the student's actor (extractor, policy MLP, action head) into ``policy``'s actor; the critic's
    point-set extractor starts from the student's extractor too (the student's value head was never trained)."""
    state = student.state_dict()
    actor = _renamed(state, ACTOR_PREFIXES)
    actor.update(_renamed(state, {"features_extractor.": ("vf_features_extractor.inner.",)}))
    missing = [k for k in actor if k not in policy.state_dict()]
    if missing:
        raise ValueError(f"init_policy: the student's network differs from the YAML's policy_kwargs ({missing[:3]} ...)")
    policy.load_state_dict(actor, strict=False)


def export_actor(policy: ActorCriticPolicy, student: PPO) -> PPO:
    """``student`` with ``policy``'s actor weights: a plain PPO on the env's observation (the critic is dropped)."""
    if not isinstance(policy, PrivilegedCriticPolicy):
        student.policy.load_state_dict(policy.state_dict())
        return student
    state = policy.state_dict()
    back = {"pi_features_extractor.inner.": ("features_extractor.", "pi_features_extractor."),
            "mlp_extractor.policy_net.": ("mlp_extractor.policy_net.",), "action_net.": ("action_net.",)}
    student.policy.load_state_dict(_renamed(state, back), strict=False)
    return student


def correct_class_prior(policy: ActorCriticPolicy, counts: np.ndarray, power: float) -> np.ndarray:
    """Subtract ``log w_a`` from the action head's bias, ``w_a = (n / (K n_a)) ** power``; returns the shift.

    Actions the expert never chose (``n_a = 0``) keep their logit (their weight was 0 in the student's fit).
    """
    counts = np.asarray(counts, dtype=float)
    present = counts > 0
    shift = np.zeros_like(counts)
    shift[present] = -power * np.log(counts.sum() / (present.sum() * counts[present]))
    bias: Any = policy.action_net.bias
    with torch.no_grad():
        bias += torch.as_tensor(shift, dtype=bias.dtype)
    return shift


def label_frequencies(env: gym.Env, student: Any, steps: int, seed: int, every_step: bool = True) -> np.ndarray:
    """The headway expert's action counts on ``steps`` env steps that ``student`` (a held policy) drives.

    ``env`` must carry :class:`agents.algos.imitation.ExpertActionInfo`; ``every_step``: label every state (the
    student's ``label_between``), else only the decision steps (every ``student.k``-th).
    """
    from agents.algos.imitation import EXPERT_KEY

    counts = np.zeros(env.action_space.n, dtype=np.int64)  # type: ignore[attr-defined]
    taken, episode = 0, 0
    k = int(getattr(student, "k", 1))
    while taken < steps:
        if callable(getattr(student, "reset", None)):
            student.reset()
        obs, info = env.reset(seed=seed + episode)
        step, done = 0, False
        while not done and taken < steps:
            if every_step or step % k == 0:
                counts[int(info[EXPERT_KEY])] += 1
            action, _ = student.predict(obs, deterministic=True)
            obs, _, terminated, truncated, info = env.step(int(np.asarray(action).reshape(-1)[0]))
            step, taken, done = step + 1, taken + 1, terminated or truncated
        episode += 1
    return counts


def anchor_coef(config: FinetuneConfig, progress: float) -> float:
    """lambda(t) of the module docstring at ``progress = t / T`` in [0, 1].

    >>> anchor_coef(FinetuneConfig(anchor_coef=2.0, anchor_fraction=0.5), 0.25)
    1.0
    >>> anchor_coef(FinetuneConfig(anchor_coef=2.0, anchor_fraction=0.5), 0.75)
    0.0
    """
    return float(config.anchor_coef * max(0.0, 1.0 - progress / config.anchor_fraction))


def critic_warming(config: FinetuneConfig, progress: float) -> bool:
    """Whether the update at ``progress = t / T`` trains the critic alone (the critic warm-up of the module docstring).

    >>> tuple(critic_warming(FinetuneConfig(critic_warmup_fraction=0.25), t) for t in (0.0, 0.2, 0.25, 1.0))
    (True, True, False, False)
    >>> critic_warming(FinetuneConfig(critic_warmup_fraction=1.0), 1.0)
    True
    """
    fraction = config.critic_warmup_fraction
    return progress < fraction or fraction >= 1.0


def actor_parameters(policy: nn.Module) -> list[nn.Parameter]:
    """The parameters of ``policy``'s actor: its feature extractor, policy MLP and action head (for a policy that
    shares its extractor with the critic, the shared extractor too)."""
    prefixes = ("features_extractor.", "pi_features_extractor.", "mlp_extractor.policy_net.", "action_net.")
    return [param for name, param in policy.named_parameters() if name.startswith(prefixes)]


class AnchoredPPO(PPO):
    """PPO whose every update is followed by ``anchor_epochs`` passes minimising lambda(t) KL(teacher || pi), and
    whose updates during the critic warm-up leave the actor alone (:func:`critic_warming`).

    ``teacher`` (a frozen actor-critic on the observation without the privileged key) and
    ``finetune`` (a :class:`FinetuneConfig`) are set by :func:`train_finetune` after construction;
    without a teacher it is plain PPO. Logs ``anchor/coef``, ``anchor/kl`` and ``finetune/critic_warmup``.
    """

    teacher: ActorCriticPolicy | None = None
    finetune: FinetuneConfig = FinetuneConfig()

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "teacher"]

    def train(self) -> None:
        progress = 1.0 - self._current_progress_remaining
        warming = critic_warming(self.finetune, progress)
        self.logger.record("finetune/critic_warmup", float(warming))
        frozen = actor_parameters(self.policy) if warming else []
        for param in frozen:
            param.requires_grad_(False)  # no gradient: Adam leaves the actor as it is
        try:
            super().train()
        finally:
            for param in frozen:
                param.requires_grad_(True)
        if self.teacher is None:
            return
        coef = anchor_coef(self.finetune, progress)
        self.logger.record("anchor/coef", coef)
        if coef <= 0 or self.finetune.anchor_epochs == 0 or warming:
            return
        self.policy.set_training_mode(True)
        kls = []
        for _ in range(self.finetune.anchor_epochs):
            for batch in self.rollout_buffer.get(self.batch_size):
                obs = batch.observations
                actor_obs = ({k: v for k, v in obs.items() if k != PRIVILEGED_KEY} if isinstance(obs, dict)
                             else obs)
                with torch.no_grad():
                    target: Any = self.teacher.get_distribution(actor_obs).distribution
                current: Any = self.policy.get_distribution(obs).distribution
                kl = torch.distributions.kl_divergence(target, current).mean()
                self.policy.optimizer.zero_grad()
                (coef * kl).backward()
                nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
                self.policy.optimizer.step()
                kls.append(float(kl.detach()))
        self.policy.set_training_mode(False)
        self.logger.record("anchor/kl", float(np.mean(kls)))


def training_wrapper(env: gym.Env, privileged: bool, shaping: dict[str, Any] | None,
                     shield: dict[str, Any] | None = None) -> gym.Env:
    """The fine-tune's wrappers of each training env: the radar shield (None: none), the privileged key (for the
    critic), then the reward shaping (:class:`agents.algos.shaping.RewardShaping`; None: highway-env's reward)."""
    if shield is not None:
        from agents.policies.shield import ShieldAction

        env = ShieldAction(env, shield)
    if privileged:
        env = PrivilegedObservation(env)
    if shaping is not None:
        from agents.algos.shaping import RewardShaping

        env = RewardShaping(env, shaping)
    return env


def _plain_model(env_id: str, run: Any, ppo_args: dict[str, Any]) -> PPO:
    """A fresh PPO of the YAML's policy on the plain env (one in-process env): what a from-scratch actor is
    exported into, so ``model.zip`` runs without the privileged key."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    from agents.evaluate import make_env

    env = DummyVecEnv([partial(make_env, env_id, run.env_kwargs)])
    try:
        return PPO(run.policy, env, device="cpu", policy_kwargs=ppo_args.get("policy_kwargs") or {})
    finally:
        env.close()


def _student_record(init_policy: str | Path) -> dict[str, Any]:
    from agents.evaluate import policy_metadata

    meta = policy_metadata(init_policy)
    if meta.get("decision_mode") not in (None, "pulse") or int(meta.get("decision_interval", 5)) != 5:
        print(f"finetune: {init_policy} was trained at decision_interval {meta.get('decision_interval')} / "
              f"{meta.get('decision_mode')}; the fine-tune decides as its YAML says", file=sys.stderr)
    return meta


def measure_prior(env_id: str, env_kwargs: dict[str, Any], student: PPO, run: Any, config: FinetuneConfig,
                  power: float, every_step: bool, seed: int) -> dict[str, Any]:
    """Measure the expert's label counts on the student's own drive and correct its logits; the record of both."""
    from agents.algos.imitation import ExpertActionInfo
    from agents.evaluate import make_env
    from agents.policies.decision import held

    env = ExpertActionInfo(make_env(env_id, env_kwargs))
    try:
        driver = held(student, run.decision_interval, run.decision_mode)
        counts = label_frequencies(env, driver, config.prior_steps, seed, every_step=every_step)
    finally:
        env.close()
    shift = correct_class_prior(student.policy, counts, power)
    return {"label_counts": counts.tolist(), "class_weight_power": power, "logit_shift": shift.round(4).tolist(),
            "steps": config.prior_steps, "seeds_from": seed}


def _settings(env_id: str, timesteps: int | None, n_envs: int | None, hyperparams: str | Path | None,
              env_kwargs: dict | None, init_policy: str | Path | None
              ) -> tuple[Any, FinetuneConfig, dict, dict | None, dict | None]:
    """The run's settings, the :class:`FinetuneConfig`, PPO's own arguments, the reward shaping and the shield
    (each None when the YAML has none; the shield as its full record)."""
    from agents.algos.hyperparams import run_settings
    from agents.algos.imitation import continued_env_kwargs
    from agents.algos.run_checks import shield_setting

    if init_policy is not None:
        if not Path(init_policy).exists():
            raise FileNotFoundError(f"--init-policy: no such student zip: {init_policy}")
        env_kwargs = continued_env_kwargs(env_id, env_kwargs, init_policy)
    run = run_settings("finetune", env_id, timesteps, n_envs, hyperparams, env_kwargs)
    config = build(FinetuneConfig, {k: v for k, v in run.hp.items() if k in FINETUNE_KEYS}, "finetune")
    ppo_args = {k: v for k, v in run.hp.items() if k not in (*FINETUNE_KEYS, "reward_shaping", "shield")}
    shaping = run.hp.get("reward_shaping")
    if shaping is not None:
        from agents.algos.shaping import ShapingConfig

        build(ShapingConfig, shaping, "reward_shaping")  # a wrong value fails here, not in a worker
    return run, config, ppo_args, shaping, shield_setting(env_id, run.hp, run.env_kwargs)


def _start_from(model: AnchoredPPO, student: PPO | None, config: FinetuneConfig) -> None:
    """The student's actor into ``model`` and, with an anchor, a frozen copy of it as the teacher."""
    model.finetune = config
    if student is None:
        return
    if config.privileged_critic:
        load_actor(model.policy, student.policy)
    else:
        model.policy.load_state_dict(student.policy.state_dict())
    if config.anchor_coef > 0:
        model.teacher = copy.deepcopy(student.policy).eval()


def _callbacks(run: Any, out: Path, checkpoint_freq: int, decisions: int, progress: bool) -> Any:
    from stable_baselines3.common.callbacks import CallbackList, CheckpointCallback

    from agents.algos.callbacks import CrashRateCallback, TqdmCallback

    callbacks: list = [CrashRateCallback()]
    if checkpoint_freq > 0:
        callbacks.append(CheckpointCallback(save_freq=max(1, checkpoint_freq // (run.n_envs * run.decision_interval)),
                                            save_path=str(out / "checkpoints"), name_prefix="finetune"))
    if progress:
        callbacks.append(TqdmCallback(decisions))
    return CallbackList(callbacks)


def _recent(model: PPO) -> dict[str, Any]:
    """Count, mean return and crash rate of the last training episodes (the model's episode buffer)."""
    recent = list(model.ep_info_buffer or [])
    return {"count": len(recent), "mean_return": float(np.mean([e["r"] for e in recent])) if recent else None,
            "crash_rate": float(np.mean([float(e.get("crashed", 0)) for e in recent])) if recent else None}


def train_finetune(env_id: str, timesteps: int | None, out: str | Path, init_policy: str | Path | None = None,
                   seed: int = 0, n_envs: int | None = None, hyperparams: str | Path | None = None,
                   env_kwargs: dict | None = None, progress: bool = True, torch_threads: int | None = 1,
                   checkpoint_freq: int = 5000) -> dict[str, Any]:
    """The fine-tuning stage of the module docstring; writes ``out/model.zip`` (the actor, a plain student zip),
    ``model.json`` / ``train.json``, ``finetune_full.zip`` (actor and privileged critic), ``monitor/``, ``tb/``.

    ``init_policy``: the student zip to start from (None: PPO from scratch with the privileged critic).
    ``env_kwargs`` are merged over the student's (its action indices mean its target speeds).
    """
    from agents.algos.run_checks import check_train_args
    from agents.algos.run_records import run_summary, tensorboard_available, write_summary
    from agents.algos.threads import limit_threads
    from agents.algos.vec_env import make_vec_env

    run, config, ppo_args, shaping, shield = _settings(env_id, timesteps, n_envs, hyperparams, env_kwargs,
                                                       init_policy)
    check_train_args(run.timesteps, run.n_envs, seed, 0, 1, checkpoint_freq)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    limit_threads(torch_threads)
    torch.manual_seed(seed)
    k = run.decision_interval
    record: dict[str, Any] = {"finetune": asdict(config), "reward_shaping": shaping, "shield": shield}
    student = None
    if init_policy is not None:
        student = PPO.load(init_policy, device="cpu")
        meta = _student_record(init_policy)
        record["init_policy"] = str(init_policy)
        if config.correct_class_prior:
            dagger = meta.get("dagger") or {}
            power = float(dagger.get("class_weight_power", 0.0))
            record["class_prior"] = measure_prior(env_id, run.env_kwargs, student, run, config, power,
                                                  bool(dagger.get("label_between", False)), seed + 20_000)
    wrapper = partial(training_wrapper, privileged=config.privileged_critic, shaping=shaping, shield=shield)
    venv = make_vec_env(env_id, run.n_envs, seed, run.env_kwargs, monitor_dir=out / "monitor", decision_interval=k,
                        decision_mode=run.decision_mode, wrapper=wrapper)
    decisions = -(-run.timesteps // k)
    tb = str(out / "tb") if tensorboard_available() else None
    policy: Any = PrivilegedCriticPolicy if config.privileged_critic else run.policy
    t0 = time.perf_counter()
    try:
        model = AnchoredPPO(policy, venv, seed=seed, verbose=0, tensorboard_log=tb, device="cpu", **ppo_args)
        _start_from(model, student, config)
        model.learn(total_timesteps=decisions, callback=_callbacks(run, out, checkpoint_freq, decisions, progress),
                    tb_log_name="finetune")
        model.save(out / "finetune_full.zip")
        export_actor(model.policy, student if student is not None else _plain_model(env_id, run, ppo_args)).save(
            out / "model.zip")
    finally:
        venv.close()
    summary = run_summary("finetune", env_id, run, seed, int(model.num_timesteps), time.perf_counter() - t0, out,
                          recent_episodes=_recent(model), interrupted=False, **record)
    write_summary(out, summary)
    return summary


__all__ = [
    "ActorFeatures", "AnchoredPPO", "CriticFeatures", "FinetuneConfig", "PrivilegedCriticPolicy", "actor_parameters",
    "anchor_coef", "correct_class_prior", "critic_warming", "export_actor", "label_frequencies", "load_actor",
    "measure_prior", "train_finetune", "training_wrapper",
]
