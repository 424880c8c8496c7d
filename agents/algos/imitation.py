"""Imitation of a privileged driver: DAgger (``rhs-slam train --algo dagger``).

The student is a stable-baselines3 ``ActorCriticPolicy`` (the same network as
PPO's, so the result is a PPO zip that ``rhs-slam evaluate`` / ``demo`` load)
that sees only the env's observation (on ``rhs-highway-slam-v0``: the radar
point cloud and the SLAM estimate). The expert, :class:`agents.policies.expert.HeadwayDriver`
(or, with the hyperparameter ``teacher: lookahead``, :class:`agents.policies.lookahead.LookaheadDriver`),
reads the simulator's true road state, which the student never sees
("learning by cheating": a privileged teacher, a sensor-only student).

DAgger (Ross, Gordon & Bagnell, 2011), iteration ``i = 0 .. I-1``:

1. Drive ``N / I`` env steps with the mixture that takes the expert's action
   with probability ``beta_i = beta_0 beta_decay ** i`` and the student's greedy action
   otherwise (``beta_0 = 1``: the expert alone in round 0); record every visited observation with
   the *expert's* action there, ``a*(s)``, whoever drove.
2. Fit the student on all data so far, ``D = D_0 u ... u D_i``, by weighted
   maximum likelihood of the expert's action:

       L(theta) = - sum_{(o, a*) in D} w_{a*} log pi_theta(a* | o) / sum w_{a*},
       w_a = (|D| / (K n_a)) ** p,

   with ``n_a`` the samples labelled ``a``, ``K`` the actions present and ``p =
   class_weight_power``; Adam, ``epochs`` passes of minibatches of ``batch_size``.
   The expert holds its lane and speed (IDLE) in most states: unweighted
   (p = 0) the student learns IDLE everywhere, and IDLE crashes into the first
   slower car; p = 1 balances the actions fully (and overshoots: the student then
   changes lane and speed where the expert would not).

Before step 2 the student is scored on the new data it has not been fitted to
(``agreement``: the fraction of states where its greedy action equals the
expert's). ``N`` counts env steps over all envs, like PPO's ``n_timesteps``,
so a DAgger and a PPO run with the same ``N`` have the same simulation budget.
With ``decision_interval: k`` (:mod:`agents.policies.decision`) the student and the expert
decide every k env steps (``N / k`` labelled decisions), the action held between.

**Labels between decisions** (``label_between``): the k - 1 states the env passes
through between two decisions are labelled too, with the action the expert would
choose there (:class:`ExpertActionInfo` with ``between = k``): k times the samples
for the same simulation budget (the student still decides every k steps; those
states are where a decision taken a little earlier or later would have been made).

**Continuation** (``init_policy``): the student starts from a trained student's
weights and DAgger goes on with ``beta_0 < 1`` on fresh data, so the rounds label
the states the trained student itself reaches (where its mistakes are); the
summary records the parent and the total budget, parent's env steps plus these.

**Resume** (``resume``): after each round the run saves what the next round needs
(:func:`save_round_state`: the aggregated data, the records, the generator, the
student and its optimizer); a run stopped or killed between rounds continues from
the last saved round with the same data and beta schedule. The envs start new
episodes (their simulator state is not saved), so a resumed run is the same
algorithm, not the same numbers. A student of many hours can so be trained in
pieces.

**Under the shield** (``shield``: :class:`agents.policies.shield.ShieldConfig` fields, ``{}`` for the defaults): every env
step's action, the student's or the expert's, goes through :class:`agents.policies.shield.ShieldAction` before the env
takes it, so the rounds visit the states the student reaches *behind the shield* (the ones it is driven in), and
the labels stay the expert's own actions; the shield is saved beside the model, so ``rhs-slam evaluate`` and the
demo drive the student through it. This is the DAgger continuation that a PPO fine-tune under the shield is
compared with at the same env-step budget.

Hyperparameters come from ``agents/hyperparams/dagger.yml`` (per env id:
``policy``, ``policy_kwargs``, ``n_envs``, ``n_timesteps``, ``env_kwargs`` and
the fields of :class:`DaggerConfig`, plus ``teacher`` (a name of :data:`TEACHERS`, default ``headway``) and
``expert``: the fields of the teacher's config, :class:`agents.policies.expert.HeadwayDriverConfig` or
:class:`agents.policies.lookahead.LookaheadDriverConfig`).
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from functools import partial
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from agents.algos.hyperparams import run_settings
from agents.algos.run_checks import check_train_args
from agents.algos.run_records import run_summary, write_summary
from agents.algos.threads import limit_threads
from agents.algos.vec_env import make_vec_env
from agents.policies.expert import HeadwayDriver, HeadwayDriverConfig
from agents.policies.lookahead import LookaheadDriver, LookaheadDriverConfig
from agents.policies.shield import ShieldAction
from rhs_common.validation import build, check_bool, check_int, check_range, check_types

__all__ = [
    "BETWEEN_KEY", "DaggerConfig", "Dataset", "EXPERT_KEY", "ExpertActionInfo", "RoundLog", "STATE_DATA", "STATE_META",
    "STATE_WEIGHTS", "TEACHERS", "agreement", "class_weights", "collect", "continued_env_kwargs", "dagger_rounds",
    "dagger_settings", "fit", "labelled_env", "load_round_state", "load_student", "make_teacher", "save_round_state",
    "teacher_config", "train_dagger", "widened_state",
]

EXPERT_KEY = "expert_action"
BETWEEN_KEY = "expert_between"


@dataclass(frozen=True)
class DaggerConfig:
    """DAgger's schedule and the student's supervised fit."""

    iterations: int = 5  # I: collect-and-fit rounds
    beta_decay: float = 0.5  # beta_i = first_beta * beta_decay ** i: the expert's share of control in round i
    first_beta: float = 1.0  # beta_0 (below 1 when the student starts trained: a continuation, ``init_policy``)
    epochs: int = 8  # passes over the aggregated data per round
    batch_size: int = 256
    learning_rate: float = 1e-3  # Adam
    class_weight_power: float = 0.5  # p: the expert's action a weighs (n / (K n_a)) ** p in the loss (0: plain)
    label_between: bool = False  # also label the k - 1 states between two decisions (k = decision_interval)

    def __post_init__(self) -> None:
        check_types(self)
        check_int("iterations", self.iterations, 1, 1000)
        check_range("beta_decay", self.beta_decay, 0.0, 1.0)
        check_range("first_beta", self.first_beta, 0.0, 1.0)
        check_int("epochs", self.epochs, 1, 1000)
        check_int("batch_size", self.batch_size, 1, 1_000_000)
        check_range("learning_rate", self.learning_rate, 0.0, 1.0, low_open=True)
        check_range("class_weight_power", self.class_weight_power, 0.0, 2.0)
        check_bool("label_between", self.label_between)


#: the privileged drivers a student can learn from (hyperparameter ``teacher``): name -> (driver, its config)
TEACHERS: dict[str, tuple[type, type]] = {"headway": (HeadwayDriver, HeadwayDriverConfig),
                                          "lookahead": (LookaheadDriver, LookaheadDriverConfig)}


def _teacher_classes(teacher: str) -> tuple[type, type]:
    if teacher not in TEACHERS:
        raise ValueError(f"teacher must be one of {sorted(TEACHERS)}, got {teacher!r}")
    return TEACHERS[teacher]


def make_teacher(env: gym.Env, teacher: str = "headway", config: Any = None):
    """The privileged driver ``teacher`` (:data:`TEACHERS`) on ``env`` with ``config`` (its config or a dict)."""
    driver, config_cls = _teacher_classes(teacher)
    return driver(env, build(config_cls, config, "expert"))


def teacher_config(hp: dict[str, Any]) -> tuple[str, Any]:
    """The hyperparameters' ``teacher`` (default ``"headway"``) and its config built from ``expert``."""
    teacher = hp.get("teacher", "headway")
    return teacher, build(_teacher_classes(teacher)[1], hp.get("expert"), "expert")


class ExpertActionInfo(gym.Wrapper):
    """Adds ``info["expert_action"]``: the teacher's action in the state just observed.

    Lives inside each (subprocess) env, so a vectorised collector gets the labels
    with the observations. ``teacher``: a name of :data:`TEACHERS` (the :class:`HeadwayDriver` by default);
    ``expert``: its config (:class:`agents.policies.expert.HeadwayDriverConfig`, ...) or a dict.
    ``every = k`` (inside a :class:`agents.policies.decision.HoldAction` of the same k, states between not labelled): the
    teacher runs only where a decision is taken, at the reset, every k-th step and the episode's last; the other
    steps carry ``None``.
    ``between = k`` (> 1; inside a :class:`agents.policies.decision.HoldAction` of the same k): the info of
    every k-th step since the reset (and of the episode's last) also carries ``info["expert_between"]``,
    the ``(observation, expert action)`` of the steps since the previous one: the states between two
    decisions, labelled with what the expert would decide there (``DaggerConfig.label_between``).

    Examples:
        >>> import gymnasium as gym, rhs_env
        >>> env = ExpertActionInfo(gym.make("rhs-highway-v0", vehicles_count=5))
        >>> _, info = env.reset(seed=0)
        >>> info["expert_action"] in range(5)
        True
    """

    def __init__(self, env: gym.Env, expert: Any = None, between: int = 1, teacher: str = "headway",
                 every: int = 1):
        super().__init__(env)
        self.driver = make_teacher(env, teacher, expert)
        check_int("between", between, 1, 1000)
        check_int("every", every, 1, 1000)
        self.between = between
        # label only the states a decision is taken in (every k-th step since the reset, and the last) unless the
        # states between are labelled too: an expensive teacher (the lookahead driver) then runs once per decision
        self.every = 1 if between > 1 else every
        self._steps = 0  # steps since the reset; (obs, label) since the last k-th step
        self._held: list[tuple[Any, int]] = []

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self._steps, self._held = 0, []
        return obs, {**info, EXPERT_KEY: self.driver.act()}

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._steps += 1
        decides = self._steps % self.every == 0 or terminated or truncated
        label = self.driver.act() if decides else None  # None: a state no decision (and no label) is taken in
        info = {**info, EXPERT_KEY: label}
        if self.between > 1:
            if self._steps % self.between == 0 or terminated or truncated:
                info[BETWEEN_KEY], self._held = self._held, []
            else:  # a state between two decisions: the student never decides here, the expert's label still holds
                self._held.append((_copy(obs), label))
        return obs, reward, terminated, truncated, info


def labelled_env(env: gym.Env, expert: Any = None, between: int = 1, teacher: str = "headway", every: int = 1,
                 shield: dict[str, Any] | None = None) -> gym.Env:
    """A DAgger run's wrappers of each env: the radar shield (:class:`agents.policies.shield.ShieldAction`; None: none), then
    :class:`ExpertActionInfo` (its arguments), so the teacher labels the states that the shielded driving reaches."""
    if shield is not None:
        env = ShieldAction(env, shield)
    return ExpertActionInfo(env, expert, between=between, teacher=teacher, every=every)


def _copy(obs: Any) -> Any:
    """A copy of an observation (a dict of arrays or an array) that the env cannot overwrite later."""
    return {k: np.array(v, copy=True) for k, v in obs.items()} if isinstance(obs, dict) else np.array(obs, copy=True)


class Dataset:
    """Aggregated (observation, expert action) pairs; dict observations are kept per key."""

    def __init__(self) -> None:
        self.obs: list[Any] = []
        self.actions: list[int] = []

    def __len__(self) -> int:
        return len(self.actions)

    def add(self, obs: Any, action: int) -> None:
        self.obs.append(obs)
        self.actions.append(int(action))

    def arrays(self) -> tuple[Any, np.ndarray]:
        """Observations stacked (a dict of arrays for Dict spaces) and the actions, int64."""
        if self.obs and isinstance(self.obs[0], dict):
            stacked: Any = {k: np.stack([o[k] for o in self.obs]) for k in self.obs[0]}
        else:
            stacked = np.stack(self.obs)
        return stacked, np.asarray(self.actions, dtype=np.int64)


def _index(obs: Any, idx: np.ndarray) -> Any:
    return {k: v[idx] for k, v in obs.items()} if isinstance(obs, dict) else obs[idx]


def _row(obs: Any, i: int) -> Any:
    return {k: np.array(v[i]) for k, v in obs.items()} if isinstance(obs, dict) else np.array(obs[i])


def collect(venv, model, steps: int, beta: float, rng: np.random.Generator, data: Dataset,
            obs: Any, labels: np.ndarray, progress=None) -> tuple[Any, np.ndarray, dict[str, Any]]:
    """Drive ``steps`` env steps (over all envs) with the beta-mixture; add (obs, expert action) to ``data``.

    ``obs`` / ``labels`` are the envs' current observations and expert actions
    (from the previous call, or a reset); the updated ones are returned with
    episode statistics of the episodes that ended here.
    """
    n = venv.num_envs
    returns, crashes, lengths = [], [], []
    taken = 0
    while taken < steps:
        student, _ = model.predict(obs, deterministic=True)
        use_expert = rng.random(n) < beta
        actions = np.where(use_expert, labels, np.asarray(student).reshape(n))
        for i in range(n):
            data.add(_row(obs, i), labels[i])
        obs, _, dones, infos = venv.step(actions)
        for info in infos:
            for between_obs, between_label in info.get(BETWEEN_KEY, ()):
                data.add(between_obs, between_label)
        labels = np.array([info[EXPERT_KEY] for info in infos], dtype=np.int64)
        for j in map(int, np.flatnonzero(dones)):
            labels[j] = venv.reset_infos[j][EXPERT_KEY]  # the new episode's first state
            episode = infos[j].get("episode") or {}
            returns.append(float(episode.get("r", np.nan)))
            lengths.append(int(episode.get("l", 0)))
            crashes.append(bool(infos[j].get("crashed", False)))
        taken += n
        if progress is not None:
            progress.update(n)
    stats = {
        "episodes": len(returns),
        "mean_return": float(np.mean(returns)) if returns else None,
        "mean_length": float(np.mean(lengths)) if lengths else None,
        "crash_rate": float(np.mean(crashes)) if crashes else None,
    }
    return obs, labels, stats


def agreement(model, obs: Any, actions: np.ndarray, batch_size: int = 1024) -> float:
    """Fraction of ``obs`` where the student's greedy action is ``actions``."""
    import torch

    policy = model.policy
    hits = 0
    with torch.no_grad():
        for start in range(0, len(actions), batch_size):
            idx = np.arange(start, min(start + batch_size, len(actions)))
            tensor, _ = policy.obs_to_tensor(_index(obs, idx))
            greedy = policy.get_distribution(tensor).get_actions(deterministic=True).cpu().numpy()
            hits += int(np.sum(greedy.reshape(-1) == actions[idx]))
    return hits / max(1, len(actions))


def class_weights(actions: np.ndarray, power: float) -> np.ndarray:
    """w_a = (n / (K n_a)) ** power per action index a (0 for actions absent from ``actions``).

    >>> class_weights(np.array([1, 1, 1, 4]), 1.0)[[1, 4]].tolist()
    [0.6666666666666666, 2.0]
    """
    counts = np.bincount(actions, minlength=int(actions.max()) + 1).astype(float)
    present = counts > 0
    w = np.zeros_like(counts)
    w[present] = (counts.sum() / (present.sum() * counts[present])) ** power
    return w


def fit(model, data: Dataset, config: DaggerConfig, rng: np.random.Generator, optimizer) -> float:
    """``config.epochs`` passes of minibatch maximum likelihood of the expert's actions; the last epoch's mean loss."""
    import torch

    policy = model.policy
    obs, actions = data.arrays()
    weights = torch.as_tensor(class_weights(actions, config.class_weight_power), dtype=torch.float32)
    policy.set_training_mode(True)
    mean_loss = float("nan")
    for _ in range(config.epochs):
        order = rng.permutation(len(actions))
        losses = []
        for start in range(0, len(order), config.batch_size):
            idx = order[start : start + config.batch_size]
            tensor, _ = policy.obs_to_tensor(_index(obs, idx))
            log_prob = policy.get_distribution(tensor).log_prob(torch.as_tensor(actions[idx]))
            w = weights[torch.as_tensor(actions[idx])]
            loss = -(w * log_prob).sum() / w.sum()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            losses.append(float(loss.detach()))
        mean_loss = float(np.mean(losses))
    policy.set_training_mode(False)
    return mean_loss


def dagger_rounds(venv, model, config: DaggerConfig, decisions: int, rng: np.random.Generator,
                  progress: bool = True, on_round: Callable[[dict[str, Any]], None] | None = None,
                  trained: bool = False, optimizer: Any = None, done_rounds: tuple[Dataset, list[dict]] | None = None,
                  state_dir: Path | None = None) -> tuple[Dataset, list[dict[str, Any]]]:
    """The DAgger loop of the module docstring over ``decisions`` labelled decisions; the data and one record per round.

    ``on_round(record)`` is called after each round's fit (checkpoints, logs). ``trained``: the student
    starts trained (a continuation), so its agreement is scored in round 0 as well. ``done_rounds``: the data
    and records of the rounds done already (:func:`load_round_state`); the loop goes on from the next
    round. ``state_dir``: where :func:`save_round_state` writes after each round.
    """
    import torch
    from tqdm.auto import tqdm

    if optimizer is None:
        optimizer = torch.optim.Adam(model.policy.parameters(), lr=config.learning_rate)
    data, records = done_rounds if done_rounds is not None else (Dataset(), [])
    obs = venv.reset()
    labels = np.array([info[EXPERT_KEY] for info in venv.reset_infos], dtype=np.int64)
    if decisions < config.iterations:
        raise ValueError(f"DAgger needs at least one decision per round: {decisions} decisions for "
                         f"dagger.iterations = {config.iterations} (raise the timesteps or lower the iterations)")
    done = records[-1]["decisions"] if records else 0  # decisions so far (samples: more with label_between)
    bar = tqdm(total=decisions, initial=done, desc="dagger", unit="decision", disable=not progress)
    for i in range(len(records), config.iterations):
        t0 = time.perf_counter()
        beta = config.first_beta * config.beta_decay**i
        start = len(data)
        steps = decisions // config.iterations + (i < decisions % config.iterations)  # the decisions split evenly
        obs, labels, stats = collect(venv, model, steps, beta, rng, data, obs, labels, bar)
        agree = agreement(model, *_new(data, start)) if i > 0 or trained else None
        loss = fit(model, data, config, rng, optimizer)
        done += steps
        records.append({"iteration": i, "beta": beta, "decisions": done, "samples": len(data),
                        "agreement_before_fit": agree, "fit_loss": loss, **stats,
                        "wall_s": round(time.perf_counter() - t0, 1)})
        print(f"dagger: round {i}: beta {beta:.3f}, {len(data)} samples, agreement "
              f"{'-' if agree is None else f'{agree:.3f}'}, loss {loss:.3f}, episodes {stats}", file=sys.stderr)
        if state_dir is not None:
            save_round_state(state_dir, data, records, rng, model, optimizer, decisions)
        if on_round is not None:
            on_round(records[-1])
    bar.close()
    return data, records


#: the files of :func:`save_round_state` in a run's output folder
STATE_DATA, STATE_META, STATE_WEIGHTS = "dagger_state.npz", "dagger_state.json", "dagger_state.pt"


def save_round_state(out: Path, data: Dataset, records: list[dict[str, Any]], rng: np.random.Generator, model,
                     optimizer, decisions: int) -> None:
    """After a round: the aggregated data (``dagger_state.npz``), the records, the generator state and the
    planned decisions (``.json``), the student's and the optimizer's state (``.pt``). Each file is written
    under a temporary name and renamed, the JSON last: a kill mid-save leaves the previous round's state."""
    import os

    import torch

    obs, actions = data.arrays()
    arrays = {f"obs.{k}": v for k, v in obs.items()} if isinstance(obs, dict) else {"obs": obs}
    np.savez(out / "dagger_state.tmp.npz", actions=actions, **arrays)
    torch.save({"policy": model.policy.state_dict(), "optimizer": optimizer.state_dict()}, out / "dagger_state.tmp.pt")
    (out / "dagger_state.tmp.json").write_text(json.dumps(
        {"rounds": len(records), "decisions": decisions, "records": records, "rng": rng.bit_generator.state}))
    os.replace(out / "dagger_state.tmp.npz", out / STATE_DATA)
    os.replace(out / "dagger_state.tmp.pt", out / STATE_WEIGHTS)
    os.replace(out / "dagger_state.tmp.json", out / STATE_META)


def load_round_state(out: Path, model, optimizer, rng: np.random.Generator,
                     decisions: int) -> tuple[Dataset, list[dict[str, Any]]] | None:
    """The state :func:`save_round_state` left in ``out`` (None when there is none): the data and the records;
    the student, the optimizer and the generator are restored in place. ``ValueError`` when the run was
    planned with another number of decisions (another ``timesteps`` or ``decision_interval``)."""
    import torch

    meta_path = out / STATE_META
    if not meta_path.exists():
        return None
    meta = json.loads(meta_path.read_text())  # the run's own state (the generator's 128-bit integers), not input
    if meta["decisions"] != decisions:
        raise ValueError(f"resume: {out} holds a run of {meta['decisions']} decisions, this one plans {decisions} "
                         "(the same timesteps and decision_interval are needed)")
    with np.load(out / STATE_DATA) as z:
        actions = z["actions"]
        keys = [k for k in z.files if k.startswith("obs")]
        obs: Any = {k[4:]: z[k] for k in keys} if keys != ["obs"] else z["obs"]
    state = torch.load(out / STATE_WEIGHTS, weights_only=False)
    model.policy.load_state_dict(state["policy"])
    optimizer.load_state_dict(state["optimizer"])
    rng.bit_generator.state = meta["rng"]
    data = Dataset()
    data.obs = [_row(obs, i) for i in range(len(actions))]
    data.actions = [int(a) for a in actions]
    return data, meta["records"]


class RoundLog:
    """After each DAgger round: a checkpoint ``out/checkpoints/dagger_round_<ii>.zip`` (two digits), the round's record as
    scalars (SB3's logger: ``out/progress.csv`` and, with tensorboard installed, ``out/tb``) and
    ``out/iterations.json`` so far, so a long run in the background can be watched and stopped."""

    def __init__(self, model, out: Path, k: int, records: list[dict[str, Any]] | None = None):
        from stable_baselines3.common.logger import configure

        from agents.algos.run_records import tensorboard_available

        self.model, self.out, self.k = model, out, k
        self.records: list[dict[str, Any]] = list(records or [])  # a resumed run's earlier rounds
        formats = ["csv", "tensorboard"] if tensorboard_available() else ["csv"]
        self.logger = configure(str(out / "tb") if "tensorboard" in formats else str(out), formats)
        (out / "checkpoints").mkdir(parents=True, exist_ok=True)

    def __call__(self, record: dict[str, Any]) -> None:
        self.records.append(record)
        self.model.save(self.out / "checkpoints" / f"dagger_round_{record['iteration']:02d}.zip")
        for key, value in record.items():
            if key != "iteration" and value is not None:
                self.logger.record(f"dagger/{key}", value)
        self.logger.dump(step=record["decisions"] * self.k)  # x-axis: env steps so far
        (self.out / "iterations.json").write_text(json.dumps(self.records, indent=2))


def dagger_settings(env_id: str, hp: dict[str, Any], env_kwargs: dict[str, Any]
                    ) -> tuple[DaggerConfig, dict[str, Any] | None]:
    """The run's :class:`DaggerConfig` and its shield record (None: none) from the YAML entry ``hp``, validated
    (errors name ``dagger.<field>`` / ``shield.<field>``; a shield on an env without radar points is refused)."""
    from agents.algos.run_checks import shield_setting

    config = build(DaggerConfig, {k: v for k, v in hp.items()
                                  if k not in ("policy_kwargs", "expert", "teacher", "shield")}, "dagger")
    return config, shield_setting(env_id, hp, env_kwargs)


def train_dagger(env_id: str, timesteps: int | None, out: str | Path, seed: int = 0, n_envs: int | None = None,
                 hyperparams: str | Path | None = None, env_kwargs: dict | None = None,
                 progress: bool = True, torch_threads: int | None = 1,
                 init_policy: str | Path | None = None, resume: bool = False) -> dict[str, Any]:
    """DAgger on ``env_id`` for ``timesteps`` env steps; writes ``out/model.zip``, ``model.json``, ``train.json``.

    Returns the summary (as in :func:`agents.algos.train.train`, with ``algo: "dagger"``
    and one record per iteration: beta, the student's agreement with the expert
    on the new states before fitting, the fit loss and the episodes driven).
    ``init_policy``: a student zip to continue from (same observation space and
    network; ``ValueError`` otherwise); the summary then has ``init_policy`` and
    ``total_timesteps`` (the parent's plus this run's env steps). ``resume``: go on from the state the
    last finished round left in ``out`` (:func:`load_round_state`; a fresh run when there is none); the
    summary then has ``resumed_from_round``.
    """
    import torch
    from stable_baselines3 import PPO

    if init_policy is not None:
        env_kwargs = continued_env_kwargs(env_id, env_kwargs, init_policy)
    run = run_settings("dagger", env_id, timesteps, n_envs, hyperparams, env_kwargs)
    if resume and not (Path(out) / STATE_META).exists():
        raise ValueError(f"--resume: no finished DAgger round in {out} to continue from (no {STATE_META}); run "
                         "without --resume to start a new run")
    teacher, expert = teacher_config(run.hp)
    config, shield = dagger_settings(env_id, run.hp, run.env_kwargs)
    check_train_args(run.timesteps, run.n_envs, seed, 0, 1, 0)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    limit_threads(torch_threads)
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    k = run.decision_interval
    venv = make_vec_env(env_id, run.n_envs, seed, run.env_kwargs, monitor_dir=out / "monitor",
                        wrapper=partial(labelled_env, expert=expert, between=k if config.label_between else 1,
                                        teacher=teacher, every=k, shield=shield),
                        decision_interval=k,
                        decision_mode=run.decision_mode)
    decisions = -(-run.timesteps // k)
    t0 = time.perf_counter()
    try:
        model = PPO(run.policy, venv, seed=seed, device="cpu", verbose=0,
                    policy_kwargs=run.hp.get("policy_kwargs") or {})
        parent = None if init_policy is None else load_student(model, init_policy)
        optimizer = torch.optim.Adam(model.policy.parameters(), lr=config.learning_rate)
        start = load_round_state(out, model, optimizer, rng, decisions) if resume else None
        resumed = None if start is None else len(start[1])  # rounds done before (the list grows in dagger_rounds)
        if resumed is not None:
            print(f"dagger: resuming after round {resumed - 1} of {config.iterations} ({out})", file=sys.stderr)
        log = RoundLog(model, out, k, records=None if start is None else start[1])
        data, records = dagger_rounds(venv, model, config, decisions, rng, progress, on_round=log,
                                      trained=parent is not None, optimizer=optimizer, done_rounds=start, state_dir=out)
        log.logger.close()
        decided = records[-1]["decisions"]
        model.num_timesteps = decided
        model.save(out / "model.zip")
    finally:
        venv.close()
    wall, timed = time.perf_counter() - t0, decided
    extra: dict[str, Any] = {}
    if resumed is not None:  # the wall time of every round, this process's and the earlier ones' (records' wall_s)
        earlier = records[:resumed]
        untimed = [r for r in earlier if "wall_s" not in r]  # rounds saved before records kept their time
        wall += sum(r["wall_s"] for r in earlier if "wall_s" in r)
        timed -= sum(r["decisions"] - (records[r["iteration"] - 1]["decisions"] if r["iteration"] else 0)
                     for r in untimed)
        extra = {"resumed_from_round": resumed, "untimed_rounds": [r["iteration"] for r in untimed]}
    extra.update({} if parent is None else {"init_policy": str(init_policy),
                                       "total_timesteps": int(parent.get("total_timesteps", parent.get("timesteps", 0)))
                                       + decided * k})
    summary = run_summary("dagger", env_id, run, seed, decided, wall, out, timed_decisions=timed,
                          dagger=asdict(config), teacher=teacher, expert=expert.to_dict(), iterations=records, interrupted=False,
                          shield=shield, **extra)
    write_summary(out, summary)
    return summary


def continued_env_kwargs(env_id: str, env_kwargs: dict[str, Any] | None, init_policy: str | Path) -> dict | None:
    """The env kwargs to continue the student ``init_policy`` on, as ``rhs-slam evaluate`` chooses them.

    On the env id it was trained on (its JSON beside the zip), its saved ``env_kwargs`` are the
    base and ``env_kwargs`` is merged over them, key by key; its action indices mean the target
    speeds it was trained with, so another ``action`` is a ``ValueError`` naming ``--init-policy``.
    On another env id, or without a JSON, ``env_kwargs`` as given. Says on stderr what it reused.
    """
    from agents.evaluate import policy_metadata

    meta = policy_metadata(init_policy)
    if meta.get("env_id") != env_id.split(":", 1)[-1]:
        return env_kwargs
    saved = dict(meta.get("env_kwargs") or {})
    merged = {**saved, **(env_kwargs or {})}
    if "action" in saved and merged["action"] != saved["action"]:
        raise ValueError(f"--init-policy {init_policy} was trained with action={saved['action']} (its action indices "
                         f"mean those target_speeds), --env-kwargs gives action={merged['action']}; continue it "
                         "with the same action, or train a new student")
    if saved and env_kwargs is None:
        print(f"dagger: continuing {init_policy} on the env kwargs it was trained on "
              f"({Path(init_policy).with_suffix('.json').name}): {json.dumps(saved)}", file=sys.stderr)
    return merged


def load_student(model, path: str | Path) -> dict[str, Any]:
    """Copy the weights of the student zip ``path`` into ``model``'s policy; returns the zip's metadata (or {}).

    Raises ``FileNotFoundError`` for a missing zip and ``ValueError`` when its observation space or
    network differs from ``model``'s (a continuation needs the same student), except for Box keys that
    ``model``'s observation adds (:func:`widened_state`).
    """
    from stable_baselines3 import PPO

    from agents.evaluate import policy_metadata

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"init_policy: no such student zip: {path}")
    parent = PPO.load(path, device="cpu")
    same = parent.observation_space == model.observation_space
    state = parent.policy.state_dict() if same else widened_state(parent, model, path)
    try:
        model.policy.load_state_dict(state)
    except RuntimeError as exc:
        raise ValueError(f"init_policy: {path} has another network than the YAML's policy_kwargs: {exc}") from None
    return policy_metadata(path)


def widened_state(parent, model, path: str | Path) -> dict[str, Any]:
    """``parent``'s weights for ``model``, whose observation has Box keys that ``parent``'s lacks (e.g. ``velocity``).

    The new keys enter :class:`agents.policies.features.PointSetExtractor`'s ``box_net`` only: its first layer gets zero
    weights on their columns and ``parent``'s on the others, so ``model`` starts as the same function of the
    observation as ``parent`` and learns what the new keys add. Any other difference of the observation spaces
    (a key removed or changed, a new point set) is a ``ValueError``.
    """
    import torch
    from gymnasium import spaces

    from agents.policies.features import box_layout

    old, new = parent.observation_space, model.observation_space
    error = ValueError(f"init_policy: {path} was trained on another observation space ({old} vs {new})")
    if not (isinstance(old, spaces.Dict) and isinstance(new, spaces.Dict)):
        raise error
    old_cols, new_cols = box_layout(old), box_layout(new)
    extra = [k for k in new.spaces if k not in old.spaces]
    shared = all(k in new.spaces and new[k] == old[k] for k in old.spaces)
    if not (shared and extra and all(isinstance(new[k], spaces.Box) and k in new_cols for k in extra)):
        raise error
    state, target = parent.policy.state_dict(), model.policy.state_dict()
    widened = False
    for name, value in target.items():
        if name.endswith("box_net.0.weight") and name in state and state[name].shape != value.shape:
            w = torch.zeros_like(value)
            for k, cols in old_cols.items():
                w[:, new_cols[k]] = state[name][:, cols]
            state[name], widened = w, True
    if not widened:  # not a PointSetExtractor student: nothing takes the new keys in
        raise error
    return state


def _new(data: Dataset, start: int) -> tuple[Any, np.ndarray]:
    """The samples added since index ``start``, stacked."""
    tail = Dataset()
    tail.obs, tail.actions = data.obs[start:], data.actions[start:]
    return tail.arrays()
