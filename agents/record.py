"""``rhs-slam record``: drive a policy and write the episodes as a Minari dataset.

Drives ``--episodes`` episodes (seeds ``seed, seed + 1, ...``) of an env with a policy (the same
``--policy`` / ``--env`` / ``--env-kwargs`` rules as :mod:`agents.evaluate`; the shipped policy by
default) and writes them with :func:`minari.create_dataset_from_buffers` under ``--out`` (a Minari
datasets folder: load with ``MINARI_DATASETS_PATH=OUT`` and ``minari.load_dataset(ID)``, or
``minari.MinariDataset(OUT/ID/data)``). The schema (:data:`SCHEMA_VERSION`, ``docs/usage/datasets.md``):

* ``observations``: the env's own observation (the radar points, each row with its range and angle
  std; on the SLAM ids also the SLAM pose, its particle std and the map), so a policy learnt
  from the dataset runs on the env as it is;
* ``actions``: what the driving policy did (behind its shield, where it has one);
* ``infos`` (one entry per observation, ``T + 1`` of them): ``expert_action``, the label of
  :class:`agents.policies.expert.HeadwayDriver` at that state (-1 where the ego is not a meta-action
  vehicle); ``kinematics``, highway-env's ground-truth Kinematics table
  (:data:`KINEMATICS_FEATURES`, :data:`KINEMATICS_VEHICLES` rows, the ego first and absolute, the
  others relative to it, m and m/s in highway-env's frame); ``world_pose``; ``points_cov``, each
  radar point's vehicle-frame 2 x 2 covariance (:func:`slam.core.association.point_covariance`,
  zeros on padding rows); ``crashed`` and ``speed``; on the SLAM ids also ``true_pose`` (map frame, the
  frame of the observation's ``pose``), ``slam_pose_cov`` (3 x 3), ``slam_pose_std``, ``slam_health``,
  ``slam_lost`` and ``position_error_m``;
* metadata: ``ref_min_score`` / ``ref_max_score``, the mean returns of a uniformly random policy and
  of IDM + MOBIL (:class:`agents.evaluate.IDMMobilPolicy`) on the first ``--reference-episodes``
  seeds of the same env (``minari.get_normalized_score``), and the env spec to rebuild the env
  (``dataset.recover_environment()`` after ``import rhs_env``).

Ctrl-C (SIGINT) or SIGTERM keeps the episodes that finished: they are written (without reference scores), the
summary says ``"interrupted": "SIGINT"`` (or ``"SIGTERM"``) and the command exits 128 + the signal number (130,
143). Both signals are handled even where the shell started the command in the background with SIGINT ignored.
The package ``minari`` (with ``h5py``) is the optional
extra ``dataset``:
``pip install -c constraints/base.txt -e ".[dataset]"``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import sys
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from agents.evaluate import (
    SHIPPED_POLICY,
    SLAM_ENV_IDS,
    env_action,
    json_default,
    load_policy,
    make_env,
    parse_env_kwargs,
    resolve_env,
    run_episode,
)
from agents.policies.expert import HeadwayDriver

if TYPE_CHECKING:
    from minari.data_collector import EpisodeBuffer

__all__ = [
    "DATASET_ID", "KINEMATICS_FEATURES", "KINEMATICS_VEHICLES", "MINARI_HINT", "NAMESPACE", "SCHEMA_VERSION",
    "SLAM_INFO_KEYS", "StepRecorder", "check_arguments", "configure", "datasets_root", "default_dataset_id",
    "record_episode", "reference_returns", "run",
]

__all__ = ["DATASET_ID", "KINEMATICS_FEATURES", "KINEMATICS_VEHICLES", "MINARI_HINT", "NAMESPACE", "SCHEMA_VERSION",
           "SLAM_INFO_KEYS", "StepRecorder", "check_arguments", "configure", "datasets_root", "default_dataset_id",
           "record_episode", "reference_returns", "run", "write_dataset"]

#: version of the layout below; bumped when a key changes meaning
SCHEMA_VERSION = 1
#: columns of the ground-truth Kinematics table (highway-env's KinematicObservation, unnormalised)
KINEMATICS_FEATURES = ("presence", "x", "y", "vx", "vy", "cos_h", "sin_h")
#: rows of the Kinematics table: the ego and the nearest others
KINEMATICS_VEHICLES = 5
#: SLAM info keys copied into the dataset's infos (float32 unless said otherwise)
SLAM_INFO_KEYS = ("true_pose", "slam_pose_cov", "slam_pose_std", "slam_health", "slam_lost", "position_error_m")
#: Minari's dataset ids: ``(namespace/)(env_name/)dataset_name-v(version)``
DATASET_ID = re.compile(r"^([A-Za-z0-9_.-]+/){0,2}[A-Za-z0-9_.-]+-v\d+$")
#: the namespace of the default ids (Minari's own datasets read ``mujoco/halfcheetah/expert-v0``)
NAMESPACE = "rhs-slam"
MINARI_HINT = 'rhs-slam record needs minari: pip install -c constraints/base.txt -e ".[dataset]"'


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--env", default=None, help="env id (default: the policy's, else rhs-highway-slam-v0)")
    parser.add_argument("--policy", default=str(SHIPPED_POLICY),
                        help="the driving policy, as rhs-slam demo takes it (default: shipped)")
    parser.add_argument("--episodes", type=int, default=10, help="episodes to record (default 10)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the first episode (then seed + 1, ...)")
    parser.add_argument("--env-kwargs", default=None, help="JSON dict passed to gym.make, over the policy's")
    parser.add_argument("--out", default=None,
                        help="Minari datasets folder (default: $MINARI_DATASETS_PATH, else ~/.minari/datasets)")
    parser.add_argument("--dataset-id", default=None,
                        help="Minari id [NAMESPACE/]ENV/NAME-vN (default: rhs-slam/<env without rhs- and -vN>/<policy>-v0)")
    parser.add_argument("--reference-episodes", type=int, default=3,
                        help="episodes of the random and IDM + MOBIL policies for ref_min/max_score (0: none)")


def default_dataset_id(env_id: str, policy: str) -> str:
    """``rhs-slam/highway-slam/shipped-v0`` for the shipped policy (``agents/data/shipped.zip``) on the default env."""
    env_name = re.sub(r"^rhs-", "", re.sub(r"-v\d+$", "", env_id.split(":")[-1]))
    name = re.sub(r"[^A-Za-z0-9_.-]+", "_", Path(policy).stem if policy.endswith(".zip") else policy)
    return f"{NAMESPACE}/{env_name}/{name}-v0"


def check_arguments(args: argparse.Namespace) -> None:
    """``ValueError`` naming the flag for counts, seeds and ids out of range."""
    if not 1 <= args.episodes <= 100_000:
        raise ValueError(f"--episodes must be in [1, 100000], got {args.episodes}")
    if not 0 <= args.reference_episodes <= 1000:
        raise ValueError(f"--reference-episodes must be in [0, 1000], got {args.reference_episodes}")
    if not 0 <= args.seed < 2**63 - args.episodes:
        raise ValueError(f"--seed must be an integer in [0, 2**63 - episodes), got {args.seed}")
    if args.dataset_id is not None and not DATASET_ID.match(args.dataset_id):
        raise ValueError(f"--dataset-id must look like [NAMESPACE/]ENV/NAME-v0 (letters, digits, '_.-'), got {args.dataset_id!r}")


def _find(env, cls_name: str):
    """The wrapper of class name ``cls_name`` in ``env``'s chain, or None."""
    e = env
    while e is not None:
        if type(e).__name__ == cls_name:
            return e
        e = getattr(e, "env", None)
    return None


class StepRecorder:
    """Builds the dataset's ``infos`` entry of one state (the module docstring's schema).

    Args:
        env: the env being driven (any of the project's ids whose ego is a highway-env vehicle).
    """

    def __init__(self, env: Any) -> None:
        from highway_env.envs.common.observation import KinematicObservation

        self.env = env
        self.kinematics = KinematicObservation(env.unwrapped, features=list(KINEMATICS_FEATURES),
                                               vehicles_count=KINEMATICS_VEHICLES, normalize=False, clip=False)
        try:
            self.expert: HeadwayDriver | None = HeadwayDriver(env)
        except ValueError:
            self.expert = None
        slam = _find(env, "SlamObservation")
        self.sensor_xy = None if slam is None else np.asarray(slam.pipeline.sensor_xy, float)

    def expert_action(self) -> int:
        """The headway expert's action at the current state (-1 without a meta-action ego)."""
        if self.expert is None:
            return -1
        try:
            return int(self.expert.act())
        except ValueError:  # the ego is not a meta-action vehicle (HeadwayDriver names it): no labels in this env
            self.expert = None
            return -1

    def __call__(self, obs: Any, info: dict[str, Any]) -> dict[str, np.ndarray]:
        from slam.core.association import point_covariance

        out: dict[str, np.ndarray] = {
            "expert_action": np.asarray(self.expert_action(), dtype=np.int64),
            "kinematics": np.asarray(self.kinematics.observe(), dtype=np.float32),
            "world_pose": np.asarray(info.get("world_pose", np.full(3, np.nan)), dtype=np.float32),
            "crashed": np.asarray(bool(info.get("crashed", False)), dtype=np.int8),
            "speed": np.asarray(float(info.get("speed", np.nan)), dtype=np.float32),
        }
        if isinstance(obs, dict) and "points" in obs:
            points = np.asarray(obs["points"], dtype=float)
            cov = np.zeros((len(points), 2, 2), dtype=np.float32)
            real = np.asarray(obs["points_mask"]) > 0
            if real.any():
                cov[real] = point_covariance(points[real], self.sensor_xy)
            out["points_cov"] = cov
        for key in SLAM_INFO_KEYS:
            if key in info:
                dtype = np.int8 if key == "slam_lost" else np.float32
                out[key] = np.asarray(info[key], dtype=dtype)
        return out


def _stack(items: list[Any]) -> Any:
    """A list of (dicts of) arrays -> (a dict of) arrays stacked on a new first axis."""
    if isinstance(items[0], dict):
        return {k: _stack([it[k] for it in items]) for k in items[0]}
    return np.stack([np.asarray(it) for it in items])


def record_episode(env: Any, policy: Any, seed: int, recorder: StepRecorder, episode_id: int) -> EpisodeBuffer:
    """One episode as a :class:`minari.data_collector.EpisodeBuffer` (observations and infos: T + 1 entries).

    Args:
        env: the env to drive.
        policy: anything with SB3's ``predict(obs, deterministic)`` (a ``reset()`` is called first when it has one).
        seed: the reset seed.
        recorder: the :class:`StepRecorder` of ``env``.
        episode_id: the buffer's id (sequential from 0 in a dataset).

    Returns:
        The episode buffer.
    """
    from minari.data_collector import EpisodeBuffer

    if callable(getattr(policy, "reset", None)):
        policy.reset()
    obs, info = env.reset(seed=seed)
    observations, infos = [obs], [recorder(obs, info)]
    actions, rewards, terminations, truncations = [], [], [], []
    done = False
    while not done:
        action, _ = policy.predict(obs, deterministic=True)
        action = env_action(action)
        obs, reward, terminated, truncated, info = env.step(action)
        observations.append(obs)
        infos.append(recorder(obs, info))
        actions.append(action)
        rewards.append(float(reward))
        terminations.append(bool(terminated))
        truncations.append(bool(truncated))
        done = terminated or truncated
    keys = set(infos[0])
    for k, entry in enumerate(infos):
        if set(entry) != keys:
            raise RuntimeError(f"episode {seed}: the info of step {k} has keys {sorted(entry)}, the reset's {sorted(keys)}")
    return EpisodeBuffer(id=episode_id, seed=seed, observations=_stack(observations), actions=np.asarray(actions),
                         rewards=rewards, terminations=terminations, truncations=truncations, infos=_stack(infos))


def reference_returns(env: Any, seeds: list[int]) -> dict[str, float]:
    """Mean returns of the random and the IDM + MOBIL policy on ``seeds`` (Minari's ref_min / ref_max score)."""
    out = {}
    for name in ("random", "idm"):
        policy = load_policy(name, env, seeds[0])
        out[name] = float(np.mean([run_episode(env, policy, s)["return"] for s in seeds]))
    return out


def datasets_root(out: str | None) -> Path:
    """``--out``, else ``$MINARI_DATASETS_PATH``, else Minari's own default folder."""
    if out is not None:
        return Path(out)
    env_path = os.environ.get("MINARI_DATASETS_PATH")
    return Path(env_path) if env_path else Path.home() / ".minari" / "datasets"


def run(args: argparse.Namespace) -> int:
    import rhs_env  # noqa: F401
    from rhs_common.validation import check_output_path

    try:
        import minari  # noqa: F401  (the optional extra: checked before any episode is driven)
    except ImportError:
        print(f"rhs-slam record: error: {MINARI_HINT}", file=sys.stderr)
        return 2
    env = None
    try:
        check_arguments(args)
        root = datasets_root(args.out)
        check_output_path("--out", str(root), directory=True)
        env_id, env_kwargs = resolve_env(args.policy, args.env, parse_env_kwargs(args.env_kwargs))
        env_kwargs.pop("render_mode", None)
        dataset_id = args.dataset_id or default_dataset_id(env_id, str(args.policy))
        if not DATASET_ID.match(dataset_id):
            raise ValueError(f"dataset id {dataset_id!r} is not a Minari id: give --dataset-id ENV/NAME-v0")
        if (root / dataset_id).exists():
            raise ValueError(f"{root / dataset_id} exists: give another --dataset-id or delete it")
        # the maps' variable-length arrays stay out of info (the dataset keeps the fixed keys only)
        extra = {"landmarks_in_info": False} if env_id.split(":")[-1] in SLAM_ENV_IDS else {}
        env = make_env(env_id, env_kwargs, **extra)
        policy = load_policy(args.policy, env, args.seed)
    except (ValueError, TypeError, FileNotFoundError, json.JSONDecodeError) as exc:
        print(f"rhs-slam record: error: {exc}", file=sys.stderr)
        if env is not None:
            env.close()
        return 2
    from tqdm.auto import tqdm

    seeds = [args.seed + k for k in range(args.episodes)]
    print(f"rhs-slam record: {args.episodes} episode(s) of {env_id} with {args.policy} -> {root / dataset_id}",
          file=sys.stderr)
    try:
        recorder = StepRecorder(env)
        buffers, refs, interrupted = _record_all(env, policy, seeds, recorder, args.reference_episodes, tqdm)
        dataset = write_dataset(root, dataset_id, buffers, env, refs, len(seeds[: args.reference_episodes]),
                                str(args.policy), _description(env_id, env_kwargs, args.policy, recorder))
    finally:
        env.close()
    summary = {
        "dataset_id": dataset_id, "path": str(root / dataset_id), "schema_version": SCHEMA_VERSION,
        "env_id": env_id, "env_kwargs": env_kwargs, "policy": str(args.policy), "seeds": seeds[: len(buffers)],
        "episodes": dataset.total_episodes, "steps": dataset.total_steps,
        "mean_return": float(np.mean([float(np.sum(b.rewards)) for b in buffers])), "reference_returns": refs,
        "expert_agreement": _agreement(buffers),
    }
    if interrupted:
        summary["interrupted"] = interrupted
    print(json.dumps(summary, indent=2, default=json_default))
    return 128 + int(signal.Signals[interrupted]) if interrupted else 0


def _record_all(env: Any, policy: Any, seeds: list[int], recorder: StepRecorder, reference_episodes: int,
                progress: Any) -> tuple[list, dict[str, float], str | None]:
    """Every episode of ``seeds``, then the reference returns; a SIGINT (Ctrl-C) or SIGTERM keeps the finished ones.

    The two signals are handled here (a background job started by a shell ignores SIGINT; SIGTERM is what ``kill``
    and job schedulers send). Returns the buffers, the reference returns (``{}`` when interrupted) and the signal's
    name (None when every episode finished).
    """
    from agents.evaluate import Interrupted, raise_interrupted

    buffers: list = []
    previous = {}
    for sig in (signal.SIGTERM, signal.SIGINT):
        try:
            previous[sig] = signal.signal(sig, raise_interrupted)
        except ValueError:  # not the main thread: the default handling stays
            pass
    try:
        for k, s in enumerate(progress(seeds, desc="record")):
            buffers.append(record_episode(env, policy, s, recorder, k))
        refs = reference_returns(env, seeds[:reference_episodes]) if reference_episodes else {}
        return buffers, refs, None
    except (KeyboardInterrupt, Interrupted) as exc:  # the finished episodes are kept (without reference scores)
        if not buffers:
            raise KeyboardInterrupt from None
        name = signal.Signals(exc.signum).name if isinstance(exc, Interrupted) else "SIGINT"
        print(f"rhs-slam record: interrupted ({name}) after {len(buffers)} of {len(seeds)} episode(s); writing those",
              file=sys.stderr)
        return buffers, {}, name
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def write_dataset(root: Path, dataset_id: str, buffers: list, env: Any, refs: dict[str, float], reference_episodes: int,
                  algorithm: str, description: str) -> Any:
    """Write ``buffers`` as the Minari dataset ``root/dataset_id`` (HDF5) with the reference scores ``refs``.

    Args:
        root: the Minari datasets folder (created).
        dataset_id: the Minari id.
        buffers: the episodes (:func:`record_episode`).
        env: the env they were recorded on (its spec is the dataset's, for ``recover_environment``).
        refs: ``{"random": return, "idm": return}`` or ``{}`` (no reference scores).
        reference_episodes: the episodes each reference return is a mean over.
        algorithm: the dataset's ``algorithm_name`` (the policy).
        description: the dataset's description.

    Returns:
        The :class:`minari.MinariDataset`.
    """
    import minari

    os.environ["MINARI_DATASETS_PATH"] = str(root.resolve())
    root.mkdir(parents=True, exist_ok=True)
    scores = {"ref_min_score": refs["random"], "ref_max_score": refs["idm"],
              "num_episodes_average_score": reference_episodes} if refs else {}
    with warnings.catch_warnings():  # Minari asks for an author, an e-mail and a code link: none to give
        warnings.filterwarnings("ignore", message=r"`(author|author_email|code_permalink)` is set to None")
        return minari.create_dataset_from_buffers(
            dataset_id, buffers, env=env, eval_env=env.spec, algorithm_name=algorithm, description=description,
            data_format="hdf5", requirements=["rhs-slam"], **scores,
        )


def _agreement(buffers) -> float | None:
    """The share of steps where the policy's action is the expert's label (None without labels)."""
    labels = np.concatenate([b.infos["expert_action"][:-1] for b in buffers])
    actions = np.concatenate([np.asarray(b.actions).reshape(-1) for b in buffers])
    if len(labels) == 0 or (labels < 0).all():
        return None
    return float(np.mean(labels == actions))


def _description(env_id: str, env_kwargs: dict[str, Any], policy: str, recorder: StepRecorder) -> str:
    expert = "HeadwayDriver labels" if recorder.expert is not None else "no expert labels (-1)"
    return (f"rhs-slam dataset schema {SCHEMA_VERSION}: {env_id} {json.dumps(env_kwargs, default=json_default)} "
            f"driven by {policy}; {expert}; infos: expert_action, kinematics {list(KINEMATICS_FEATURES)}, "
            "world_pose, points_cov, crashed, speed and the SLAM pose, covariance and health "
            "(docs/usage/datasets.md).")
