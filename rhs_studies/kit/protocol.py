"""One select-then-test protocol for the driving comparisons, and their specs as data.

A comparison (:class:`Comparison`, read from a YAML file by :func:`load_spec`) names its rows by role:

1. **Choice** on the validation seeds: each candidate (:class:`Row`: a policy, greedy or sampled, behind the shield
   its record keeps or with some of its fields changed) and the ``reference`` rows; the choice ``rule`` picks one
   candidate: ``paired_gain`` (the highest paired return gain over ``choice.reference``), ``mean_return`` (the
   highest mean return) or ``fewest_collisions`` (ties broken by the higher mean return). Nothing else is read
   from these seeds.
2. **Test** on the test seeds, driven once: the ``test`` rows (``$chosen`` stands for the chosen candidate's policy
   and shield), each paired against ``paired.against``; the targets (``targets.kind``: ``finetune``, the RL
   study's :func:`rhs_studies.kit.driving.targets` on the chosen arm against ``targets.control``; ``vs_idm``,
   return and collisions of one row against IDM + MOBIL) judged on the chosen arm.

Seeds are named sets of the ledger (:mod:`rhs_studies.kit.seeds`) or ``{first, episodes}``; a test set must be
fresh (no ledger set but those in ``test_seeds.allow``). :func:`run_comparison` drives a comparison and returns its
result: the same blocks the RL studies' pages render (``validation``: seeds, gains, chosen, rows, runs; ``test``:
seeds, rows, the paired block, targets, runs), so their tables come out as before.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rhs_common.input_files import read_yaml
from rhs_common.validation import build, check_choice, check_int, check_range
from rhs_studies.kit import driving, seeds
from rhs_studies.kit.tables import collisions, mean_return, paired, row_summary, slim_runs

CHOSEN = "$chosen"
RULES = ("paired_gain", "mean_return", "fewest_collisions")
TARGET_KINDS = ("finetune", "vs_idm", "none")


@dataclass(frozen=True)
class Row:
    """One row of a seed set: ``policy`` (an arm of :data:`rhs_studies.kit.driving.ARMS`, a start of
    :data:`~rhs_studies.kit.driving.STARTS`, a scripted reference of :data:`~rhs_studies.kit.driving.SCRIPTED`, or
    ``$chosen``) under the result key ``key`` (default: the policy's name)."""

    policy: str
    key: str = ""
    #: greedy actions (False: sampled, seeded by the episode's seed)
    deterministic: bool = True
    #: fields of the shield its record keeps changed for this row (None: the shield as saved)
    shield: Mapping[str, float] | None = None

    def __post_init__(self) -> None:
        known = (*driving.ARMS, *driving.STARTS, *driving.SCRIPTED, CHOSEN)
        check_choice("policy", self.policy, known)
        if self.policy in driving.SCRIPTED and self.shield:
            raise ValueError(f"shield: a scripted reference ({self.policy}) drives behind no shield")

    @property
    def name(self) -> str:
        """The result key of the row."""
        return self.key or self.policy


@dataclass(frozen=True)
class SeedSpec:
    """A seed set: a set of the ledger by ``name``, or ``episodes`` seeds from ``first``."""

    name: str = ""
    first: int = -1
    episodes: int = 0
    #: ledger sets this set may touch (a study rerunning on its own set)
    allow: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if bool(self.name) == (self.first >= 0):
            raise ValueError("give either name (a set of the seed ledger) or first and episodes")
        if self.name:
            seeds.seed_set(self.name)
        else:
            check_int("episodes", self.episodes, 2, 10**5)
        for a in self.allow:
            seeds.seed_set(a)

    def seeds(self) -> list[int]:
        """The seeds of the set."""
        return seeds.seed_set(self.name).seeds if self.name else seeds.consecutive(self.first, self.episodes)


@dataclass(frozen=True)
class Choice:
    """How the candidate is chosen on the validation seeds."""

    rule: str = "paired_gain"
    #: the row the paired gains are against (``paired_gain``)
    reference: str = ""

    def __post_init__(self) -> None:
        check_choice("rule", self.rule, RULES)
        if self.rule == "paired_gain" and not self.reference:
            raise ValueError("reference: the paired_gain rule needs the row the gains are against")


@dataclass(frozen=True)
class Paired:
    """The paired block of the test: each row (but ``skip``) against the row ``against``, under ``key``."""

    against: str
    key: str = "vs_start"
    skip: tuple[str, ...] = ()


@dataclass(frozen=True)
class Targets:
    """What the test judges on the chosen arm (``row``: its result key, default ``$chosen``)."""

    kind: str = "finetune"
    row: str = CHOSEN
    #: ``finetune``: the DAgger control of the same budget
    control: str | None = None
    #: ``vs_idm``: the least return over IDM + MOBIL's and the most collisions per episode
    return_vs_idm: float = 1.0
    collision_rate: float = 0.04

    def __post_init__(self) -> None:
        check_choice("kind", self.kind, TARGET_KINDS)
        check_range("return_vs_idm", self.return_vs_idm, 0.0, 10.0)
        check_range("collision_rate", self.collision_rate, 0.0, 1.0)


@dataclass(frozen=True)
class Comparison:
    """A select-then-test comparison (the module's docstring)."""

    name: str
    validation_seeds: SeedSpec
    test_seeds: SeedSpec
    candidates: tuple[Row, ...]
    test: tuple[Row, ...]
    choice: Choice = field(default_factory=Choice)
    #: rows driven beside the candidates on the validation seeds (the choice's reference)
    reference: tuple[Row, ...] = ()
    paired: Paired | None = None
    targets: Targets = field(default_factory=lambda: Targets(kind="none"))
    #: episode length in seconds (None: the env's; a short smoke run)
    episode_s: float | None = None
    title: str = ""

    def __post_init__(self) -> None:
        if len(self.candidates) < 1:
            raise ValueError("candidates: at least one")
        keys = [r.name for r in self.candidates]
        if len(set(keys)) != len(keys):
            raise ValueError(f"candidates: keys given twice: {keys}")
        test_keys = [r.name for r in self.test]
        if CHOSEN not in [r.policy for r in self.test]:
            raise ValueError("test: one row must be the chosen candidate ($chosen)")
        if self.choice.rule == "paired_gain" and self.choice.reference not in [r.name for r in self.reference]:
            raise ValueError(f"choice.reference: {self.choice.reference!r} is not a reference row")
        if self.paired is not None and self.paired.against not in test_keys:
            raise ValueError(f"paired.against: {self.paired.against!r} is not a test row ({test_keys})")
        if self.episode_s is not None:
            check_range("episode_s", self.episode_s, 0.2, 600.0)
        val, test = self.validation_seeds.seeds(), self.test_seeds.seeds()
        if set(val) & set(test):
            raise ValueError(f"test_seeds: {test[0]}-{test[-1]} overlap the validation seeds {val[0]}-{val[-1]}")


def _rows(value: Any, path: str) -> tuple[Row, ...]:
    if not isinstance(value, list):
        raise TypeError(f"{path} must be a list of rows, got {type(value).__name__}")
    return tuple(build(Row, v, f"{path}[{k}]") for k, v in enumerate(value))


def comparison(value: Mapping[str, Any], path: str = "") -> Comparison:
    """A :class:`Comparison` from its mapping (a spec file's content); errors name the field path."""
    if not isinstance(value, Mapping):
        raise TypeError(f"{path or 'spec'} must be a mapping of the comparison's fields")
    value = dict(value)
    for k in ("candidates", "test", "reference"):
        if k in value:
            value[k] = _rows(value[k], f"{path}.{k}" if path else k)
    names = {f.name for f in dataclasses.fields(Comparison)}
    unknown = sorted(k for k in value if k not in names)
    if unknown:
        raise ValueError(f"{path + ': ' if path else ''}unknown fields {unknown}; the fields are {sorted(names)}")
    return build(Comparison, value, path)


def load_spec(path: str | Path) -> Comparison:
    """The comparison of the YAML file ``path`` (:func:`rhs_common.input_files.read_yaml`); ``ValueError`` /
    ``TypeError`` naming the file and the field."""
    path = Path(path)
    doc = read_yaml(path)
    try:
        return comparison(doc or {})
    except (TypeError, ValueError) as err:
        raise type(err)(f"{path}: {err}") from None


Drive = Callable[[Row, list[int]], list[dict]]


def row_driver(workers: int, ship_dir: Path = driving.SHIPPED_DIR, episode_s: float | None = None) -> Drive:
    """A function driving one :class:`Row` (``$chosen`` already resolved) on seeds with
    :func:`rhs_studies.kit.driving.drive_row`."""

    def drive(row: Row, seed_list: list[int]) -> list[dict]:
        return driving.drive_row(row.policy, seed_list, workers, ship_dir, row.deterministic, row.shield, episode_s)

    return drive


def _choose(spec: Comparison, val: dict[str, list[dict]]) -> tuple[str, dict[str, Any] | None]:
    keys = [r.name for r in spec.candidates]
    if spec.choice.rule == "paired_gain":
        gains = {k: paired(val[k], val[spec.choice.reference]) for k in keys}
        return max(keys, key=lambda k: gains[k]["mean"]), gains
    if spec.choice.rule == "mean_return":
        return max(keys, key=lambda k: mean_return(val[k])), None
    return min(keys, key=lambda k: (collisions(val[k]), -mean_return(val[k]))), None


def _resolve(row: Row, chosen: Row) -> Row:
    """``row`` with ``$chosen`` replaced by the chosen candidate (its policy and shield; the row's own greedy or
    sampled actions) and its key by the chosen candidate's when the row has none."""
    if row.policy != CHOSEN:
        return row
    return Row(chosen.policy, row.key or chosen.policy, row.deterministic,
               {**(chosen.shield or {}), **(row.shield or {})} or None)


def _targets(spec: Comparison, rows: dict[str, Any], test: dict[str, list[dict]], chosen: Row) -> dict[str, Any]:
    t = spec.targets
    key = chosen.policy if t.row == CHOSEN else t.row
    if t.kind == "finetune":
        return driving.targets(rows, test, key, t.control)
    if t.kind == "vs_idm":
        s = rows[key]
        vs_idm = s["return"]["mean"] / rows["idm"]["return"]["mean"]
        return {"arm": chosen.policy, "return_vs_idm": vs_idm, "collision_rate": s["collision_rate"],
                "met": {"return_vs_idm": vs_idm >= t.return_vs_idm, "collisions": s["collision_rate"] <= t.collision_rate}}
    return {}


def run_comparison(spec: Comparison, drive: Drive, validation_seeds: list[int] | None = None,
                   test_seeds: list[int] | None = None, given: Mapping[str, list[dict]] | None = None,
                   log: str = "comparison") -> dict[str, Any]:
    """Steps 1 and 2 of the protocol (the module's docstring); the result without provenance.

    Args:
        spec: the comparison.
        drive: drives one row on seeds (:func:`row_driver`; tests pass a fake).
        validation_seeds: the choice's seeds (None: the spec's).
        test_seeds: the test's seeds (None: the spec's).
        given: test rows already driven on these test seeds (result key -> episodes), taken instead of driven.
        log: the name progress lines on stderr start with.

    Returns:
        ``{"validation": {...}, "test": {...}}`` (the module's docstring).
    """
    val_seeds = spec.validation_seeds.seeds() if validation_seeds is None else validation_seeds
    t_seeds = spec.test_seeds.seeds() if test_seeds is None else test_seeds
    t0 = time.perf_counter()
    val = {r.name: drive(r, val_seeds) for r in (*spec.reference, *spec.candidates)}
    chosen_key, gains = _choose(spec, val)
    chosen = next(r for r in spec.candidates if r.name == chosen_key)
    print(f"{log}: chose {chosen_key} ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    test: dict[str, list[dict]] = {}
    for row in spec.test:
        r = _resolve(row, chosen)
        test[r.name] = dict(given or {}).get(r.name) or drive(r, t_seeds)
    rows = {k: row_summary(r) for k, r in test.items()}
    validation: dict[str, Any] = {"seeds": val_seeds}
    if gains is not None:
        validation["gains"] = gains
    validation.update({"chosen": chosen_key, "rows": {k: row_summary(r) for k, r in val.items()}, "runs": slim_runs(val)})
    out: dict[str, Any] = {"seeds": t_seeds, "rows": rows}
    if spec.paired is not None:
        p = spec.paired
        out[p.key] = {k: paired(r, test[p.against]) for k, r in test.items() if k not in (p.against, *p.skip)}
    out["targets"] = _targets(spec, rows, test, chosen)
    out["runs"] = slim_runs(test)
    return {"validation": validation, "test": out}


__all__ = ["CHOSEN", "Choice", "Comparison", "Paired", "Row", "SeedSpec", "Targets", "comparison", "load_spec",
           "row_driver", "run_comparison"]
