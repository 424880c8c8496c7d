"""Evaluate a driving policy with SLAM in the loop (``rhs-slam evaluate``).

Runs ``episodes`` episodes on seeds ``seed, seed + 1, ...`` (so two policies
evaluated with the same seed meet the same traffic) and reports, as mean and
spread (standard deviation, and standard error of the mean) over episodes:
return, collision rate, mean speed, episode length and, on envs with the SLAM
wrapper, the position RMSE of the estimated trajectory (sqrt of the mean
squared per-step position error, no alignment: the map frame is the start
pose), the heading RMSE and the final map RMSE (Hungarian matching).
On ``rhs-highway-v0`` (ground truth) the SLAM fields are ``null``.

Env and env kwargs: a policy zip written by ``rhs-slam train`` has a JSON
beside it (``model.zip`` -> ``model.json``) naming the env id and ``env_kwargs``
it was trained on. Without ``--env`` the policy's env is used; with the same
env, its ``env_kwargs`` are the defaults and ``--env-kwargs`` is merged over
them (key by key, top level), so the policy always meets the observation it
was trained on unless asked otherwise. A policy trained with a ``decision_interval``
k > 1 (saved in the same JSON, :mod:`agents.policies.decision`) is loaded as a
:class:`agents.policies.decision.HeldPolicy`: it decides every k env steps and repeats its
action between, so every policy is scored per env step on the same seeds. A record with a ``shield``
(:mod:`agents.policies.shield`) drives the policy behind the radar safety shield; ``--shield`` puts any policy behind
it, ``--no-shield`` drives a shielded one without. The default policy is the shipped one,
``agents/data/shipped.zip`` (:data:`agents.SHIPPED_POLICY`, with its ``.json`` record; a copy of the experiment
``agents/data/rl/shield_flank_explore_lane_time.zip``, which its record names): a PPO fine-tune (privileged
critic, 40k env steps, :mod:`agents.algos.finetune`) of the DAgger student below, trained and driven behind the radar
shield, whose lane-change rule (``lane_time_s`` 2.5) was chosen on validation seeds (:mod:`rhs_studies.rl_lane_rule_trial`).
Its start, ``agents/data/rl/dagger_cruise30_close.zip``, is the DAgger student of
:class:`agents.policies.expert.HeadwayDriver` (:mod:`agents.algos.imitation`), ``agents/data/dagger_rhs_highway_slam.zip``,
continued with DAgger for 80k env steps (``rl/dagger_continue_80k.zip``), then 40k with the headway driver
at 30 m/s and a 2.0 s gap (``rl/dagger_cruise30_gap.zip``) and 40k more with it following at 5 m
(``agents/hyperparams/dagger_cruise30_close.yml``), driven behind the radar shield (the policy shipped before);
``ppo_rhs_highway_slam.zip`` is PPO with the student's budget (it learned always-SLOWER).

An evaluation estimated above an hour (:func:`estimate_hours`, from the measured steps/s) needs
``--yes``. SIGTERM or Ctrl-C stop it at once: the finished episodes are written (``interrupted``
names the signal, ``partial`` is true) and the command exits 128 + the signal number, as ``rhs-slam train`` does.
``--out`` and ``--figure`` are written atomically (:mod:`rhs_common.output_files`), and refused before any
episode when one is the policy or its record, they are one path, or the figure's suffix is not a format
matplotlib writes; so are ``--shield`` with ``--no-shield`` and ``--stochastic`` with a scripted driver.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

from agents import SHIPPED_POLICY as _SHIPPED_ROLE
from agents.algos.run_checks import parse_env_kwargs
from agents.policies.decision import held
from agents.policies.expert import HeadwayDriver
from agents.policies.lookahead import LookaheadDriver
from agents.policies.shield import ShieldedPolicy, check_shield_env, shield_record
from rhs_env.idm_driver import swap_ego_for_idm
from rhs_env.registration import SLAM_ENV_SPECS
from slam.core.trajectory_formats import FORMAT_CHOICES, formats_of
from slam.gym.trajectory import sim_time

__all__ = [
    "ConstantPolicy", "DAGGER_CONTINUED_POLICY", "DAGGER_CRUISE30_CLOSE_POLICY", "DAGGER_CRUISE30_GAP_POLICY",
    "DAGGER_POLICY", "DAGGER_TRUTH_POLICY", "DATA_DIR", "DEFAULT_ENV", "IDMMobilPolicy", "Interrupted", "raise_interrupted",
    "MAX_UNCONFIRMED_HOURS", "PPO_POLICY", "PPO_TRUTH_POLICY", "PointColumnAdapter", "RADAR_STEPS_PER_S",
    "RL_FINETUNE_POLICY", "RandomPolicy", "SHIPPED_POLICY", "SHIPPED_TRUTH_POLICY", "SLAM_ENV_IDS", "STEPS_PER_S",
    "check_flags", "check_spaces", "configure", "env_action", "episode_steps", "estimate_hours", "evaluate",
    "figure_suffixes", "is_scripted", "json_default", "load_policy", "make_env", "model_shield", "parse_env_kwargs",
    "parse_shield", "plot_summary", "policy_files", "policy_metadata", "resolve_env", "run", "run_episode",
    "seed_sampling", "summarize", "write_run_trajectories",
]

DATA_DIR = Path(__file__).parent / "data"
#: DAgger students of agents.policies.expert.HeadwayDriver, 80k env steps each: on radar + SLAM (shipped) and ground truth
DAGGER_POLICY = DATA_DIR / "dagger_rhs_highway_slam.zip"
DAGGER_TRUTH_POLICY = DATA_DIR / "dagger_rhs_highway_truth.zip"
#: PPO at its own budget (agents/hyperparams/ppo.yml, 40k env steps): results/policies.md compares
PPO_POLICY = DATA_DIR / "ppo_rhs_highway_slam.zip"
PPO_TRUTH_POLICY = DATA_DIR / "ppo_rhs_highway_truth.zip"
#: the DAgger student continued for 80k more env steps from DAGGER_POLICY (rhs_studies/rl_finetune.py's
#: ``dagger_continue_80k`` arm; 2 collisions in 200 fresh episodes against the student's 7)
DAGGER_CONTINUED_POLICY = DATA_DIR / "rl" / "dagger_continue_80k.zip"
#: DAgger continued from DAGGER_CONTINUED_POLICY with the 30 m/s headway teacher: 2.0 s gap (dagger_cruise30_gap.yml),
#: then 5 m standstill gap (dagger_cruise30_close.yml); the second's record drives it behind the radar shield
DAGGER_CRUISE30_GAP_POLICY = DATA_DIR / "rl" / "dagger_cruise30_gap.zip"
DAGGER_CRUISE30_CLOSE_POLICY = DATA_DIR / "rl" / "dagger_cruise30_close.zip"
#: the PPO fine-tune of DAGGER_CRUISE30_CLOSE_POLICY under the shield (rhs_studies/rl_finetune.py's
#: ``shield_flank_explore`` arm) behind the lane rule rhs_studies/rl_lane_rule_trial.py chose and tested (``--ship``)
RL_FINETUNE_POLICY = DATA_DIR / "rl" / "shield_flank_explore_lane_time.zip"
#: the policy of ``rhs-slam demo`` / ``evaluate`` by default (:data:`agents.SHIPPED_POLICY`, ``agents/data/shipped.zip``:
#: a byte copy of RL_FINETUNE_POLICY, its record naming that lineage), and the ground-truth student of the same expert
SHIPPED_POLICY, SHIPPED_TRUTH_POLICY = _SHIPPED_ROLE, DAGGER_TRUTH_POLICY
DEFAULT_ENV = "rhs-highway-slam-v0"


def is_scripted(policy: str | Path) -> bool:
    """``"random"``, ``"constant:<action>"``, ``"idm"``, ``"idm:<m/s>"``, ``"headway[:<k>]"`` or ``"lookahead[:<k>]"``:
    policies that need no file."""
    text = str(policy)
    return (text in ("random", "idm", "headway", "lookahead")
            or text.startswith(("constant:", "idm:", "headway:", "lookahead:")))


class ConstantPolicy:
    """The same action at every step (``"constant:4"``: SLOWER with highway-env's DiscreteMetaAction)."""

    def __init__(self, action_space, action: int):
        if not action_space.contains(action):
            raise ValueError(f"constant action {action} is not in the action space {action_space}")
        self.action = action

    def predict(self, obs, deterministic: bool = True):
        return self.action, None


class IDMMobilPolicy:
    """highway-env's own IDM + MOBIL driver in the ego's seat (a scripted reference).

    At the first ``predict`` after each reset the ego (an ``MDPVehicle`` that
    follows meta-actions) is replaced, in ``road.vehicles``, ``controlled_vehicles``
    and the action type, by a ``highway_env.vehicle.behavior.IDMVehicle`` at the
    same dynamical state (``IDMVehicle.create_from``) with desired speed
    ``target_speed`` (:func:`rhs_env.idm_driver.swap_ego_for_idm`; a steering-only
    ego, the racetrack's, gets its lane as the target lane first). From then on the env's ``road.act()`` lets it decide at the
    simulation rate like the traffic does: IDM longitudinal control,

        a = a_max [1 - (v / v0)^delta - (d*(v, dv) / d)^2],
        d* = d0 + v T + v dv / (2 sqrt(a_max b)),

    and MOBIL lane changes (a change is taken when the ego's acceleration gain
    exceeds the imposed braking on the new follower by ``LANE_CHANGE_MIN_ACC_GAIN``
    and that braking stays under ``LANE_CHANGE_MAX_BRAKING_IMPOSED``). The
    meta-action it returns (IDLE) is ignored by ``IDMVehicle.act``. Rewards,
    collisions, radar and SLAM see the swapped vehicle (they read
    ``env.unwrapped.vehicle`` / ``road.vehicles`` each step). ``target_speed``
    defaults to the highest target speed of the env's ``DiscreteMetaAction``
    (30 m/s on the highway ids: the top of the reward's speed range).
    """

    def __init__(self, env, target_speed: float | None = None):
        base = env.unwrapped
        if not hasattr(base, "road") or not hasattr(base, "action_type"):
            raise ValueError("the idm policy needs a highway-env env (env.unwrapped.road)")
        if target_speed is None:
            speeds = getattr(base.action_type, "target_speeds", None)
            target_speed = float(np.max(speeds)) if speeds is not None else 30.0
        if not 0.0 < float(target_speed) <= 60.0:
            raise ValueError(f"idm target speed must be in (0, 60] m/s, got {target_speed}")
        self.env = env
        self.target_speed = float(target_speed)
        self.idle = 1  # DiscreteMetaAction IDLE; IDMVehicle.act ignores it

    def predict(self, obs, deterministic: bool = True):
        swap_ego_for_idm(self.env, self.target_speed)
        return self.idle, None


class RandomPolicy:
    """Uniformly random actions from the env's action space (seeded)."""

    def __init__(self, action_space, seed: int = 0):
        self.space = action_space
        self.space.seed(seed)

    def predict(self, obs, deterministic: bool = True):
        return self.space.sample(), None


def policy_metadata(policy: str | Path, required: bool = False) -> dict[str, Any]:
    """A policy's record (env id, env kwargs, training settings): the JSON beside the zip (or beside the file a
    symbolic link names), else the one inside the zip (:func:`agents.policies.policy_record.read_record`); ``{}`` for a
    scripted driver. Without any record: ``{}``, or (``required``) a ``ValueError`` naming the missing JSON."""
    from agents.policies.policy_record import read_record

    if is_scripted(policy):
        return {}
    return read_record(policy, required=required)


#: ids whose info carries the SLAM metrics (slam.gym.metrics_info.SlamMetricsInfo)
SLAM_ENV_IDS = tuple(env_id for env_id, _ in SLAM_ENV_SPECS)


def resolve_env(
    policy: str | Path, env_id: str | None = None, env_kwargs: dict | None = None
) -> tuple[str, dict[str, Any]]:
    """The env id and kwargs to run ``policy`` on (see the module docstring for the rules).

    Raises ``FileNotFoundError`` for a missing policy file (before any env is built).
    """
    if not is_scripted(policy) and not Path(policy).exists():
        raise FileNotFoundError(f"policy file not found: {policy}")
    from rhs_env.registration import check_env_id

    if env_id is not None:
        check_env_id(env_id)
    meta = policy_metadata(policy, required=True)
    meta_env = meta.get("env_id")
    env_id = env_id or meta_env or DEFAULT_ENV
    base = dict(meta.get("env_kwargs") or {}) if env_id == meta_env else {}
    return env_id, {**base, **(env_kwargs or {})}


def make_env(env_id: str, kwargs: dict[str, Any], **extra: Any):
    """``gym.make(env_id, **kwargs)``; on the SLAM ids the info keeps the true and estimated maps
    (``landmarks_in_info``) for the episode record. Bad kwargs raise the configs' own ``ValueError`` /
    ``TypeError``, which name the field."""
    import gymnasium as gym

    import rhs_env  # noqa: F401  (registers the ids)

    if env_id.split(":")[-1] in SLAM_ENV_IDS:
        extra.setdefault("landmarks_in_info", True)
    return gym.make(env_id, **{**kwargs, **extra})


def load_policy(policy: str | Path, env=None, seed: int = 0):
    """``"random"``, ``"constant:<action>"``, ``"idm[:<m/s>]"``, ``"headway[:<k>]"``
    (:class:`agents.policies.expert.HeadwayDriver`, the DAgger expert; with k, pulsed every k steps), ``"lookahead[:<k>]"``
    (:class:`agents.policies.lookahead.LookaheadDriver`, the rollout teacher), or a
    stable-baselines3 zip (PPO, DQN or a DAgger student: from the JSON beside it, else PPO and DQN tried in turn).

    With ``env``, the policy's observation space is checked against the env's. A zip whose JSON
    has ``decision_interval`` k > 1 comes back as a :class:`agents.policies.decision.HeldPolicy` (decides every
    k ``predict`` calls; :func:`run_episode` resets it at each episode start); one whose JSON has a
    ``shield`` (the shipped policy, or a fine-tune trained under it: :mod:`agents.policies.shield`) behind a
    :class:`agents.policies.shield.ShieldedPolicy`.
    """
    if is_scripted(policy):
        if env is None:
            raise ValueError(f"policy {policy!r} needs the env for its action space")
        if str(policy) == "random":
            return RandomPolicy(env.action_space, seed)
        if str(policy).split(":", 1)[0] in ("headway", "lookahead"):
            return _privileged_driver(str(policy), env)
        if str(policy).split(":", 1)[0] == "idm":
            speed = None
            if ":" in str(policy):
                try:
                    speed = float(str(policy).split(":", 1)[1])
                except ValueError:
                    raise ValueError(f"idm policy must be 'idm' or 'idm:<target speed m/s>', got {policy!r}") from None
            return IDMMobilPolicy(env, speed)
        try:
            action = int(str(policy).split(":", 1)[1])
        except ValueError:
            raise ValueError(f"constant policy must be 'constant:<int action>', got {policy!r}") from None
        return ConstantPolicy(env.action_space, action)
    path = Path(policy)
    if not path.exists():
        raise FileNotFoundError(f"policy file not found: {path}")
    if path.is_dir():
        return _load_rllib(path, env)
    from stable_baselines3 import DQN, PPO

    classes = {"ppo": PPO, "dqn": DQN, "dagger": PPO}  # a DAgger student is a PPO policy (agents.algos.imitation)
    algo = str(policy_metadata(path).get("algo", "")).lower()
    order = [classes[algo]] if algo in classes else [PPO, DQN]
    errors = []
    model = None
    for cls in order:
        try:
            model = cls.load(path, device="cpu")  # type: ignore[attr-defined]  # PPO / DQN classmethod
            break
        except Exception as exc:
            errors.append(f"{cls.__name__}: {exc}")
    if model is None:
        raise ValueError(f"{path} is not a PPO or DQN model ({'; '.join(errors)})")
    if env is not None:
        check_spaces(model, env, path)
        model = PointColumnAdapter.wrap(model, env)
    meta = policy_metadata(path, required=True)
    return _with_saved_shield(held(model, meta.get("decision_interval", 1), meta.get("decision_mode", "hold")),
                              meta, env)


def _with_saved_shield(policy: Any, meta: dict[str, Any], env=None) -> Any:
    """``policy`` behind the radar shield saved in its record (``meta["shield"]``), else itself."""
    if meta.get("shield") is None:
        return policy
    if env is not None:
        check_shield_env(env.observation_space)
    return ShieldedPolicy(policy, meta["shield"])


def _privileged_driver(policy: str, env):
    """``"headway"``: the HeadwayDriver deciding every step; ``"headway:<k>"``: deciding every k steps, IDLE
    between (decision_mode pulse: how the DAgger students drive and how the expert labelled their states);
    ``"lookahead[:<k>]"`` the same for the :class:`agents.policies.lookahead.LookaheadDriver` (the rollout teacher)."""
    name, _, k_text = policy.partition(":")
    driver = HeadwayDriver(env) if name == "headway" else LookaheadDriver(env)
    if not k_text:
        return driver
    try:
        k = int(k_text)
    except ValueError:
        raise ValueError(f"{name} policy must be '{name}' or '{name}:<decision interval>', got {policy!r}") from None
    return held(driver, k, "pulse")


def _load_rllib(path: Path, env=None):
    """The RLModule of an RLlib checkpoint directory (``rhs-slam train --backend rllib``); a run with a decision
    interval k > 1 (``decision_interval`` in the JSON beside the directory) comes back as a
    :class:`agents.policies.decision.HeldPolicy`, and one trained under the shield behind it, as a zip does."""
    from agents.policies.rllib_policy import MODULE_SUBDIR, RLlibPolicy, is_rllib_checkpoint

    if not is_rllib_checkpoint(path):
        raise ValueError(f"{path} is a directory but not an RLlib checkpoint (no {'/'.join(MODULE_SUBDIR)})")
    model = RLlibPolicy(path)
    if env is not None:
        check_spaces(model, env, path)
    meta = policy_metadata(path, required=True)
    return _with_saved_shield(held(model, meta.get("decision_interval", 1), meta.get("decision_mode", "hold")),
                              meta, env)


class PointColumnAdapter:
    """A policy trained on fewer ``points`` columns (the first round's x, y, vr, amplitude) run on the
    wider observation: ``predict`` gets the first columns it was trained on; everything else passes."""

    def __init__(self, model, width: int) -> None:
        self.model, self.width = model, int(width)
        self.observation_space = model.observation_space
        self.action_space = model.action_space

    @classmethod
    def wrap(cls, model, env):
        """``model`` itself when its ``points`` width equals the env's, else the adapter."""
        width = _points_width(model.observation_space)
        return model if width is None or width == _points_width(env.observation_space) else cls(model, width)

    def predict(self, obs, *args, **kwargs):
        obs = {**obs, "points": obs["points"][..., : self.width]}
        return self.model.predict(obs, *args, **kwargs)

    def __getattr__(self, name):
        return getattr(self.model, name)


def _points_width(space) -> int | None:
    from gymnasium import spaces

    if isinstance(space, spaces.Dict) and "points" in space.spaces:
        shape = space.spaces["points"].shape
        return int(shape[-1]) if shape else None
    return None


def _space_summary(space) -> str:
    from gymnasium import spaces

    if isinstance(space, spaces.Dict):
        return "{" + ", ".join(f"{k}: {_space_summary(v)}" for k, v in space.spaces.items()) + "}"
    return f"{type(space).__name__}{tuple(getattr(space, 'shape', ()) or ())}"


def check_spaces(model, env, path: str | Path = "policy") -> None:
    """Raise ``ValueError`` when the env's observation / action space differ from the policy's."""
    from gymnasium import spaces

    def layout(space, points_width: int | None = None):
        if isinstance(space, spaces.Dict):
            return {k: layout(v, points_width if k == "points" else None) for k, v in space.spaces.items()}
        shape = tuple(getattr(space, "shape", ()) or ())
        if points_width is not None and shape:  # fewer point columns than the env: fed by PointColumnAdapter
            shape = shape[:-1] + (min(shape[-1], points_width),)
        return (type(space).__name__, shape, getattr(space, "n", None))

    width = _points_width(model.observation_space)
    if layout(model.observation_space) != layout(env.observation_space, width):
        raise ValueError(
            f"{path} was trained on observations {_space_summary(model.observation_space)} but the env gives "
            f"{_space_summary(env.observation_space)}: use the env id and env kwargs it was trained on "
            f"(see {Path(path).with_suffix('.json').name})"
        )
    if layout(model.action_space) != layout(env.action_space):
        raise ValueError(f"{path} acts in {model.action_space} but the env expects {env.action_space}")


def _stats(values: list[float | None]) -> dict[str, float | int | None]:
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], dtype=float)
    if v.size == 0:
        return {"mean": None, "std": None, "sem": None, "min": None, "max": None, "n": 0}
    return {
        "mean": float(v.mean()),
        "std": float(v.std()),
        "sem": float(v.std(ddof=1) / np.sqrt(v.size)) if v.size > 1 else None,
        "min": float(v.min()),
        "max": float(v.max()),
        "n": int(v.size),
    }


def env_action(action) -> Any:
    """A predicted action as the env takes it (a numpy scalar array -> int)."""
    a = np.asarray(action)
    return int(a) if a.ndim == 0 and np.issubdtype(a.dtype, np.integer) else action


def episode_steps(env) -> int | None:
    """Steps of a full episode (``duration * policy_frequency``), or None when the env does not say."""
    try:
        cfg = env.unwrapped.config
        return int(round(float(cfg["duration"]) * float(cfg["policy_frequency"])))
    except (AttributeError, KeyError, TypeError, ValueError):
        return None


def seed_sampling(seed: int) -> None:
    """Seed torch's global generator, which stable-baselines3 samples a policy's actions from, so that an episode's
    sampled actions depend on its seed alone (not on the episodes a process ran before it)."""
    import torch

    torch.manual_seed(seed)


def run_episode(
    env,
    policy,
    seed: int,
    deterministic: bool = True,
    frames: list | None = None,
    trace: list | None = None,
    bar: Any = None,
) -> dict[str, Any]:
    """One episode; returns its return, crash flag, mean speed, SLAM errors and the trajectories.

    ``frames`` collects ``env.render()`` per step; ``trace`` the ``(obs, info)`` of the reset and of
    every step; ``bar`` (a tqdm bar) is advanced by one per step. A policy with a ``reset()``
    (:class:`agents.policies.decision.HeldPolicy`) is reset first; with ``deterministic=False`` the sampling is seeded with
    ``seed`` (:func:`seed_sampling`).
    """
    if callable(getattr(policy, "reset", None)):
        policy.reset()
    if not deterministic:
        seed_sampling(seed)
    obs, info = env.reset(seed=seed)
    if frames is not None:
        frames.append(env.render())
    if trace is not None:
        trace.append((obs, info))
    total, steps, speeds, pos_err, head_err2 = 0.0, 0, [], [], []
    true_xy, est_xy, true_poses, est_poses, times = [], [], [], [], []
    crashed, done = False, False
    while not done:
        action, _ = policy.predict(obs, deterministic=deterministic)
        obs, reward, terminated, truncated, info = env.step(env_action(action))
        total += float(reward)
        steps += 1
        crashed = crashed or bool(info.get("crashed", False))
        speeds.append(float(info.get("speed", np.nan)))
        if "position_error_m" in info:
            pos_err.append(float(info["position_error_m"]))
            head_err2.append(float(info.get("heading_error_rad", np.nan)) ** 2)
            true_xy.append(np.asarray(info["true_pose"][:2], dtype=float).tolist())
            est_xy.append(np.asarray(info["estimated_pose"][:2], dtype=float).tolist())
            true_poses.append(np.asarray(info["true_pose"], dtype=float).reshape(3).tolist())
            est_poses.append(np.asarray(info["estimated_pose"], dtype=float).reshape(3).tolist())
            times.append(sim_time(env, steps))
        if frames is not None:
            frames.append(env.render())
        if trace is not None:
            trace.append((obs, info))
        if bar is not None:
            bar.update(1)
        done = terminated or truncated
    map_rmse = info.get("map_rmse_m")  # absent until a landmark is matched
    shield = model_shield(policy)
    return {
        "seed": seed,
        "return": total,
        "steps": steps,
        "crashed": crashed,
        "mean_speed": float(np.nanmean(speeds)) if speeds and np.isfinite(speeds).any() else None,
        "position_rmse_m": float(np.sqrt(np.mean(np.square(pos_err)))) if pos_err else None,
        "final_position_error_m": pos_err[-1] if pos_err else None,
        "heading_rmse_rad": float(np.sqrt(np.nanmean(head_err2))) if head_err2 else None,
        "map_rmse_m": None if map_rmse is None else float(map_rmse),
        "map_matched": info.get("map_matched"),
        "map_missed": info.get("map_missed"),
        "map_spurious": info.get("map_spurious"),
        "position_error_m": pos_err,
        "true_xy": true_xy,
        "estimated_xy": est_xy,
        "time_s": times,  # the env's simulated time of each pose (one policy period per step)
        "true_poses": true_poses,
        "estimated_poses": est_poses,
        "landmarks_true": np.asarray(info.get("true_landmarks", np.zeros((0, 2)))).reshape(-1, 2).tolist(),
        "landmarks_est": np.asarray(info.get("estimated_landmarks", np.zeros((0, 2)))).reshape(-1, 2).tolist(),
        "shield_overrides": None if shield is None else dict(shield.overrides),
    }


def write_run_trajectories(run: dict[str, Any], directory: str | Path, formats: tuple[str, ...] = ("tum",)) -> list[Path]:
    """Write an episode's estimated and true trajectories (:func:`run_episode`'s ``estimated_poses``, ``true_poses``
    and ``time_s``) as ``seed_<seed>_est.tum`` / ``_gt.tum`` (and ``.kitti``) in ``directory``, for ``evo_ape``
    (no alignment: its APE is the episode's ``position_rmse_m``); nothing for an episode without SLAM poses.

    Args:
        run: one episode's record.
        directory: the output folder.
        formats: some of ``("tum", "kitti")``.

    Returns:
        The paths written.
    """
    from slam.core.trajectory_formats import write_trajectory_pair

    if not run.get("estimated_poses"):
        return []
    return write_trajectory_pair(directory, f"seed_{run['seed']}", np.asarray(run["time_s"]),
                                 np.asarray(run["estimated_poses"]), np.asarray(run["true_poses"]), formats)


def check_trajectories(args: argparse.Namespace) -> None:
    """``ValueError`` before any episode unless ``--trajectories`` is a folder that can be written and the env
    (``--env``, else the policy's) is a SLAM id, whose info has the estimated and true poses."""
    from rhs_common.validation import check_output_path

    check_output_path("--trajectories", args.trajectories, directory=True)
    env_id, _ = resolve_env(args.policy, args.env, parse_env_kwargs(args.env_kwargs))
    if env_id.split(":")[-1] not in SLAM_ENV_IDS:
        raise ValueError(f"--trajectories: {env_id} has no SLAM estimate to export; use one of {', '.join(SLAM_ENV_IDS)}")


def summarize(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Mean and spread over episodes of the per-episode results of :func:`run_episode`."""
    crashes = [bool(r["crashed"]) for r in runs]
    return {
        "episodes": len(runs),
        "return": _stats([r["return"] for r in runs]),
        "collision_rate": float(np.mean(crashes)) if runs else None,
        "collisions": int(np.sum(crashes)),
        "mean_speed_mps": _stats([r["mean_speed"] for r in runs]),
        "episode_length": _stats([r["steps"] for r in runs]),
        "position_rmse_m": _stats([r["position_rmse_m"] for r in runs]),
        "heading_rmse_rad": _stats([r["heading_rmse_rad"] for r in runs]),
        "map_rmse_m": _stats([r["map_rmse_m"] for r in runs]),
        "shield_overrides": _override_totals(runs),
    }


def model_shield(policy: Any):
    """The :class:`agents.policies.shield.RadarShield` a loaded policy drives through, or None."""
    return policy.shield if isinstance(policy, ShieldedPolicy) else None


def _override_totals(runs: list[dict[str, Any]]) -> dict[str, int] | None:
    """The shield's replacements (:mod:`agents.policies.shield`) summed over episodes, per reason; None when unshielded."""
    counts: list[dict[str, int]] = [r["shield_overrides"] for r in runs if r.get("shield_overrides") is not None]
    return {k: int(sum(c[k] for c in counts)) for k in counts[0]} if counts else None


#: env steps per second on the project's 2-core machine (results/benchmark.md, default radar): the
#: ground-truth env, and any env with the radar (the SLAM envs are a little slower still)
STEPS_PER_S = {"rhs-highway-v0": 44.6}
RADAR_STEPS_PER_S = 15.7
#: longest evaluation (estimated, hours) started without ``max_hours=None`` (``--yes``)
MAX_UNCONFIRMED_HOURS = 1.0


def estimate_hours(env_id: str, episodes: int, steps_per_episode: int | None) -> float:
    """Rough wall time of ``episodes`` full episodes (hours), at :data:`STEPS_PER_S` / :data:`RADAR_STEPS_PER_S`."""
    rate = STEPS_PER_S.get(env_id.split(":")[-1], RADAR_STEPS_PER_S)
    return episodes * (steps_per_episode or 200) / rate / 3600


class Interrupted(Exception):
    """SIGTERM or SIGINT arrived during :func:`evaluate` (raised by its handler, caught by it)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


def raise_interrupted(signum, frame) -> None:
    """A signal handler that raises :class:`Interrupted` (the evaluation and the recorder stop cleanly on it)."""
    raise Interrupted(signum)


def evaluate(
    policy: str | Path,
    env_id: str | None = None,
    episodes: int = 5,
    seed: int = 0,
    env_kwargs: dict | None = None,
    progress: bool = True,
    deterministic: bool = True,
    max_hours: float | None = MAX_UNCONFIRMED_HOURS,
    shield: dict[str, Any] | bool | None = None,
) -> dict[str, Any]:
    """Evaluate ``policy`` on ``episodes`` seeded episodes; returns the JSON-ready summary.

    ``shield`` (a :class:`agents.policies.shield.ShieldConfig` as a dict; ``{}`` or ``True``: its defaults) drives the
    policy through the radar safety shield, in place of any shield saved beside it; ``False`` drives it without
    one; None: as its record says.

    ``env_id`` / ``env_kwargs`` default to the ones saved beside the policy (:func:`resolve_env`).
    An evaluation estimated (:func:`estimate_hours`) longer than ``max_hours`` is refused with a
    ``ValueError`` before any episode (``None``: no limit). SIGTERM / SIGINT (Ctrl-C) stop it at
    once (from the main thread): the episode under way is dropped, the summary covers the finished
    ones and has ``interrupted`` (the signal's name); otherwise ``interrupted`` is None.
    """
    import signal

    from tqdm.auto import tqdm

    import rhs_env  # noqa: F401

    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    env_id, kwargs = resolve_env(policy, env_id, env_kwargs)
    previous = {}
    interrupted = None
    runs: list[dict[str, Any]] = []
    env = model = None
    try:
        for sig in (signal.SIGTERM, signal.SIGINT):
            try:
                previous[sig] = signal.signal(sig, raise_interrupted)
            except ValueError:  # not the main thread: the default handling stays
                pass
        env = make_env(env_id, kwargs)
        model = load_policy(policy, env, seed)
        if isinstance(model, ShieldedPolicy) and shield is not None:
            model = model.model  # the saved shield is replaced or dropped
        if shield is not None and shield is not False:
            check_shield_env(env.observation_space)
            model = ShieldedPolicy(model, {} if shield is True else shield)
        per_episode = episode_steps(env)
        hours = estimate_hours(env_id, episodes, per_episode)
        if max_hours is not None and hours > max_hours:
            raise ValueError(f"--episodes {episodes}: {episodes} x {per_episode or 'about 200'} env steps on {env_id} "
                             f"take about {hours:.1f} h ({hours / 24:.1f} days) at the measured speed; pass --yes "
                             f"(evaluate(max_hours=None)) to run it, or evaluate fewer episodes")
        with tqdm(total=episodes * per_episode if per_episode else None, desc="evaluate", unit="step",
                  disable=not progress) as bar:
            for k in range(episodes):
                bar.set_postfix(episode=f"{k + 1}/{episodes}")
                runs.append(run_episode(env, model, seed + k, deterministic=deterministic, bar=bar))
    except Interrupted as exc:
        interrupted = signal.Signals(exc.signum).name
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
        if env is not None:
            env.close()
    return {
        "policy": str(policy),
        "env_id": env_id,
        "env_kwargs": kwargs,
        "seed": seed,
        "seeds": [seed + k for k in range(len(runs))],
        "deterministic": deterministic,
        "shield": shield_record(getattr(model_shield(model), "config", None)),
        "interrupted": interrupted,
        **summarize(runs),
        "runs": runs,
    }


def plot_summary(summary: dict[str, Any], path: str | Path) -> None:
    """Per-episode returns, the first episode's true vs estimated trajectory and map, position error over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = summary["runs"]
    slam = bool(runs and runs[0]["true_xy"])
    fig, axes = plt.subplots(1, 3 if slam else 1, figsize=(16 if slam else 6, 4.2), squeeze=False)
    axes = axes[0]
    ax = axes[0]
    ax.bar(range(len(runs)), [r["return"] for r in runs], color=["C3" if r["crashed"] else "C0" for r in runs])
    ax.set(xlabel="episode", ylabel="return", title=f"{summary.get('env_id', '')}: return per episode (red = crashed)")
    if slam:
        r0 = runs[0]
        ax = axes[1]
        t, e = np.asarray(r0["true_xy"]), np.asarray(r0["estimated_xy"])
        ax.plot(t[:, 0], t[:, 1], "k-", label="true trajectory")
        ax.plot(e[:, 0], e[:, 1], "C1--", label="estimated trajectory")
        lt, le = np.asarray(r0["landmarks_true"]), np.asarray(r0["landmarks_est"])
        if lt.size:
            ax.plot(lt[:, 0], lt[:, 1], "ks", ms=4, mfc="none", label="true landmarks (seen)")
        if le.size:
            ax.plot(le[:, 0], le[:, 1], "C1x", ms=4, label="estimated landmarks")
        pos = r0["position_rmse_m"]
        mp = r0["map_rmse_m"]
        ax.set(
            xlabel="x (m)",
            ylabel="y (m)",
            title=f"episode 1 (seed {r0['seed']}): position RMSE {pos:.2f} m, map RMSE "
            + (f"{mp:.2f} m" if mp is not None else "n/a"),
        )
        ax.legend(fontsize=8)
        ax = axes[2]
        for _k, r in enumerate(runs[:10]):
            ax.plot(
                np.arange(1, len(r["position_error_m"]) + 1), r["position_error_m"], lw=1, label=f"seed {r['seed']}"
            )
        ax.set(xlabel="step (SLAM cycle)", ylabel="position error (m)", title="SLAM position error")
        if len(runs) <= 10:
            ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--policy",
        default=str(SHIPPED_POLICY),
        help="SB3 zip, RLlib checkpoint dir, 'random', 'constant:ACTION', 'idm[:M/S]' (IDM + MOBIL driver), "
        "'headway[:K]' (the DAgger expert, deciding every K steps) or 'lookahead[:K]' (the rollout teacher; "
        "default: shipped policy)",
    )
    parser.add_argument("--env", default=None, help=f"env id (default: the policy's, else {DEFAULT_ENV})")
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0, help="first episode seed (episodes use seed, seed + 1, ...)")
    parser.add_argument(
        "--env-kwargs", default=None, help="JSON dict passed to gym.make, merged over the policy's saved env kwargs"
    )
    parser.add_argument("--stochastic", action="store_true", help="sample actions instead of the greedy action")
    parser.add_argument(
        "--shield", nargs="?", const="{}", default=None, metavar="JSON",
        help="drive through the radar safety shield (agents.policies.shield; optional JSON of ShieldConfig fields, e.g. "
        "'{\"front_time_s\": 1.5}'), in place of a shield saved beside the policy",
    )
    parser.add_argument("--no-shield", action="store_true",
                        help="drive a policy saved with the shield (the shipped one) without it")
    parser.add_argument("--out", required=True, help="output JSON file")
    parser.add_argument("--figure", default=None, help="output PNG (default: the --out path with .png)")
    parser.add_argument("--trajectories", default=None, metavar="DIR",
                        help="also write each episode's estimated and true trajectories here (seed_<seed>_est.tum, "
                        "seed_<seed>_gt.tum) for evo_ape / evo_traj (the SLAM ids)")
    parser.add_argument("--trajectory-format", default="tum", choices=FORMAT_CHOICES,
                        help="format of --trajectories: tum (timestamped), kitti (3x4 matrices) or both (default: tum)")
    parser.add_argument("--no-progress", action="store_true")
    parser.add_argument("--yes", action="store_true",
                        help=f"run an evaluation estimated above {MAX_UNCONFIRMED_HOURS:g} h (refused otherwise)")


def policy_files(policy: str | Path) -> list[tuple[str, Path]]:
    """The files a policy is read from (the zip or checkpoint folder, and the JSON record beside it or beside the
    file a symbolic link names) as ``(what, path)`` pairs; none for a scripted driver."""
    if is_scripted(policy):
        return []
    records = {Path(policy).with_suffix(".json"), Path(os.path.realpath(policy)).with_suffix(".json")}
    return [("--policy", Path(policy)), *(("the policy's record", r) for r in sorted(records))]


def figure_suffixes() -> tuple[str, ...]:
    """The suffixes matplotlib's Agg canvas saves (``.png``, ``.pdf``, ``.svg``, ...), with the dot."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    return tuple(sorted(f".{ext}" for ext in FigureCanvasAgg.get_supported_filetypes()))


def check_flags(args: argparse.Namespace) -> None:
    """``ValueError`` for flags that contradict each other, and for outputs that cannot be written as asked
    (checked before any episode: an output onto an input, a figure format matplotlib does not write)."""
    from rhs_common.output_files import check_output_file

    if args.shield is not None and args.no_shield:
        raise ValueError("--shield and --no-shield contradict each other: pass one of them")
    if args.shield is not None and str(args.policy).split(":", 1)[0] == "idm":
        raise ValueError(f"--shield: the {args.policy!r} driver is highway-env's IDMVehicle, which ignores every "
                         "action, so a shield could not act on it; drop --shield (or drive 'headway' behind it)")
    if args.stochastic and is_scripted(args.policy):
        raise ValueError(f"--stochastic: the scripted driver {args.policy!r} has no action distribution to sample "
                         "(it is for a trained policy); drop --stochastic")
    inputs = policy_files(args.policy)
    check_output_file("--out", args.out, inputs=inputs)
    figure = args.figure or Path(args.out).with_suffix(".png")
    check_output_file("--figure" if args.figure else "--figure (default: --out with .png)", figure,
                      inputs=[*inputs, ("--out", args.out)], suffixes=figure_suffixes())


def run(args: argparse.Namespace) -> int:
    from rhs_common.output_files import atomic_output, write_text_atomic

    try:
        check_flags(args)
        if args.trajectories is not None:
            check_trajectories(args)
        if args.episodes < 1 or args.episodes > 100_000:
            raise ValueError(f"--episodes must be in [1, 100000], got {args.episodes}")
        if not 0 <= args.seed < 2**63:
            raise ValueError(f"--seed must be an integer in [0, 2**63), got {args.seed}")
        summary = evaluate(
            args.policy,
            args.env,
            args.episodes,
            args.seed,
            parse_env_kwargs(args.env_kwargs),
            progress=not args.no_progress,
            deterministic=not args.stochastic,
            max_hours=None if args.yes else MAX_UNCONFIRMED_HOURS,
            shield=False if args.no_shield else None if args.shield is None else parse_shield(args.shield),
        )
        if args.trajectories is not None:  # the finished episodes' (all of them unless interrupted)
            summary["trajectory_files"] = [str(f) for r in summary["runs"] for f in write_run_trajectories(
                r, args.trajectories, formats_of(args.trajectory_format))]
    except (ValueError, TypeError, FileNotFoundError, json.JSONDecodeError) as exc:
        print(f"rhs-slam evaluate: error: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out)
    figure = Path(args.figure) if args.figure else out.with_suffix(".png")
    summary["figure"] = str(figure)
    summary["partial"] = summary["interrupted"] is not None  # the episodes finished before the signal only
    with atomic_output(figure) as tmp:  # the figure first: a JSON record is the sign the run was written out
        plot_summary(summary, tmp)
    write_text_atomic(out, json.dumps(summary, indent=2, default=json_default))
    brief = {k: v for k, v in summary.items() if k != "runs"}
    print(json.dumps(brief, indent=2, default=json_default))
    if summary["interrupted"]:
        import signal

        print(f"rhs-slam evaluate: interrupted ({summary['interrupted']}) after {summary['episodes']} of "
              f"{args.episodes} episodes; wrote them to {out}, marked \"partial\": true", file=sys.stderr)
        return 128 + int(signal.Signals[summary["interrupted"]])
    return 0


def parse_shield(text: str) -> dict[str, Any]:
    """``--shield``'s JSON object of :class:`agents.policies.shield.ShieldConfig` fields, validated."""
    from rhs_common.input_files import parse_json

    value = parse_json(text, "--shield")
    if not isinstance(value, dict):
        raise TypeError(f"--shield must be a JSON object of ShieldConfig fields, got {text!r}")
    shield_record(value)  # a wrong field fails here, naming shield.<field>
    return value


def json_default(value: Any) -> Any:
    """``json.dumps(..., default=json_default)``: numpy scalars and arrays as Python numbers and lists."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serializable: {type(value).__name__}")
