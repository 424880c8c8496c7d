"""What a training run writes about itself: its summary, the record inside each checkpoint and beside each zip.

:func:`run_summary` (the record of a finished run, ``DIR/train.json``), :func:`run_record` (what a checkpoint zip
carries to be driven and resumed), :func:`write_summary` (the summary and the zips' records, written atomically,
:mod:`agents.policies.policy_record`), :func:`metadata_path` (``model.zip`` -> ``model.json``) and
:func:`tensorboard_available` (whether the run can write TensorBoard logs).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from agents.algos.hyperparams import RunSettings

__all__ = ["metadata_path", "run_record", "run_summary", "tensorboard_available", "write_summary"]


def metadata_path(policy: str | Path) -> Path:
    """The JSON written beside a policy zip (``model.zip`` -> ``model.json``)."""
    return Path(policy).with_suffix(".json")


def run_summary(algo: str, env_id: str, run: RunSettings, seed: int, decisions: int, wall: float, out: Path,
                timed_decisions: int | None = None, **extra: Any) -> dict[str, Any]:
    """The record of a finished run that every trainer writes (``extra`` appended: the algorithm's own fields).

    ``timesteps`` counts env steps, ``decisions x decision_interval`` (an episode cut short by a crash
    takes fewer); ``steps_per_s`` is timesteps over the wall time ``wall`` (s), or, where ``wall`` covers
    only ``timed_decisions`` of them (a resumed run whose earlier parts were not timed), those over ``wall``.
    """
    wall = max(wall, 1e-9)
    timed = decisions if timed_decisions is None else timed_decisions
    return {
        "algo": algo,
        "env_id": env_id.split(":", 1)[-1],
        "env_kwargs": run.env_kwargs,
        "policy": run.policy,
        "timesteps": int(decisions) * run.decision_interval,
        "decision_interval": run.decision_interval,
        "decision_mode": run.decision_mode,
        "decisions": int(decisions),
        "n_envs": run.n_envs,
        "seed": seed,
        "wall_time_s": round(wall, 1),
        "steps_per_s": round(int(timed) * run.decision_interval / wall, 2),
        "hyperparams": run.hp_record,
        "model": str(out / "model.zip"),
        **extra,
    }


def run_record(algo: str, env_id: str, run: RunSettings, seed: int) -> dict[str, Any]:
    """What a checkpoint of a run carries inside its zip: the env and settings to drive and to resume it with."""
    return {"algo": algo, "env_id": env_id.split(":", 1)[-1], "env_kwargs": run.env_kwargs, "policy": run.policy,
            "decision_interval": run.decision_interval, "decision_mode": run.decision_mode, "n_envs": run.n_envs,
            "seed": seed, "planned_timesteps": run.timesteps, "hyperparams": run.hp_record}


def write_summary(out: Path, summary: dict[str, Any]) -> None:
    """``out/train.json`` and the record of ``model.zip`` (and ``best_model.zip``): the JSON beside each zip and
    a copy inside it (:mod:`agents.policies.policy_record`), all written atomically."""
    from agents.policies.policy_record import embed_record, write_bytes_atomic

    text = json.dumps(summary, indent=2)
    write_bytes_atomic(out / "train.json", text.encode())
    for name in ("model.zip", "best_model.zip"):
        if name == "model.zip" or (out / name).exists():
            record = summary if name == "model.zip" else {**summary, "model": str(out / name)}
            if (out / name).exists():
                embed_record(out / name, record)
            write_bytes_atomic(metadata_path(out / name), json.dumps(record, indent=2).encode())


def tensorboard_available() -> bool:
    try:
        import tensorboard  # noqa: F401
    except ImportError:
        return False
    return True
