"""The seed ledger: every set of episode seeds a driving study has trained near, chosen, tuned or judged on.

A comparison judged on seeds that chose its arm, or tuned its shield, is not a fresh test. Each set is named here
once, with the study that drove it and what for; :func:`overlap` says which sets a list of seeds touches, so that a
study refuses to call a driven set fresh (:func:`check_fresh`). A new study that drives a new set adds it here.

The studies that drive no policy (radar, pattern, SLAM, registration, video) draw scene and noise seeds from the
sets of :data:`SCENE_SETS`, named here too but outside the driving ledger's freshness check. Every study's seed
default is read from a named set (:func:`first`), so the number a study starts from says which set it draws:

>>> first("policies_table"), first("shield_validation", 50), first("fast_radar_calibration")
(1000, 4050, 100000)

>>> [s.name for s in overlap(range(6099, 6101))]
['rl_confirm_test']
>>> overlap(range(9000, 9100))
[]
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from rhs_common.validation import check_int


@dataclass(frozen=True)
class SeedSet:
    """One named set of consecutive seeds ``first``..``last`` (both included) and who drove it for what."""

    name: str
    first: int
    last: int
    #: the study (or training) that drove these seeds and what it read from them
    use: str

    def __post_init__(self) -> None:
        check_int(f"seed set {self.name}.first", self.first, 0, 2**31 - 1)
        check_int(f"seed set {self.name}.last", self.last, self.first, 2**31 - 1)

    @property
    def seeds(self) -> list[int]:
        """The seeds of the set, in order."""
        return list(range(self.first, self.last + 1))

    def __contains__(self, seed: object) -> bool:
        return isinstance(seed, int) and self.first <= seed <= self.last


#: every seed set driven so far, in the order the studies drove them
LEDGER: tuple[SeedSet, ...] = (
    SeedSet("training", 0, 999, "the training envs of every policy (seeds 0..; the studies' scene seeds too)"),
    SeedSet("policies_table", 1000, 1099, "evaluate_policies (the policies table) and crash_analysis (1000-1049)"),
    SeedSet("heldout_2000", 2000, 2049, "the held-out evaluations of the students' budget ablation (crash_analysis)"),
    SeedSet("rl_finetune_heldout", 3000, 3099, "rl_finetune: the RL arms judged (looked at more than once)"),
    SeedSet("shield_validation", 4000, 4099, "teachers and shield_sensing: the shield tuned, the shield arms chosen"),
    SeedSet("lane_analysis", 5000, 5059, "the lane-change crashes analysed, the lane rules measured"),
    SeedSet("rl_confirm_test", 6000, 6099, "rl_confirm: the chosen fine-tune tested once"),
    SeedSet("rl_confirm_validation", 7000, 7099, "rl_confirm: the fine-tune and PPO from scratch chosen"),
    SeedSet("lane_rule_test", 8000, 8099, "rl_lane_rule_trial: the fine-tune behind the chosen lane rule tested"),
    SeedSet("training_eval", 10000, 10999, "the training runs' evaluation envs"),
    SeedSet("pose_covariance_heldout", 12000, 12039, "pose_covariance: the pose covariance models judged (12000-12019 "
            "at every model version; 12020-12039 first with the map-start term and 40 calibration drives)"),
    SeedSet("pose_calibration", 13000, 13039, "slam.gym.pose_calibration: the pose covariance's factors fitted "
            "(13000-13009 until the map-start term; 13000-13039 since)"),
    SeedSet("campaign_validation", 20000, 20099, "the training campaign: the checkpoints chosen (driving.campaign)"),
    SeedSet("campaign_pilot_test", 21000, 21009, "the campaign pilot's shield table, fast and exact env"),
    SeedSet("campaign_test", 21100, 21199, "the campaign's shield table: every arm with and without the shield, exact "
            "and fast env, driven once (the scripted arms first; the campaign's chosen runs when it ends)"),
    SeedSet("bc_dataset", 30000, 30519, "bc_from_dataset: the shipped policy's recorded episodes (the Minari dataset)"),
    SeedSet("bc_test", 31000, 31029, "bc_from_dataset: the behaviour clone and the shipped policy compared once"),
    SeedSet("campaign_training", 1_000_000, 99_999_999, "the training campaign's training envs (driving.campaign)"),
)
BY_NAME = {s.name: s for s in LEDGER}

#: the seed sets of the studies that drive no policy: scene, traffic and noise seeds. Not driving episodes, so outside
#: :data:`LEDGER` and its freshness check (the ``scenes`` set shares its numbers with ``training``)
SCENE_SETS: tuple[SeedSet, ...] = (
    SeedSet("scenes", 0, 999, "the radar, pattern, SLAM, registration and video studies' scene and noise seeds "
            "(seed 0 by default; fig5a and registration_in_loop take seeds 0..N-1)"),
    SeedSet("low_snr_slam", 100, 107, "low_snr_slam: the SLAM at low SNR (100-102 by default, 100-107 published)"),
    SeedSet("fast_radar_calibration", 100_000, 100_099, "calibrate_fast_radar: the fast radar's detection tables"),
    SeedSet("fast_radar_fidelity", 200_000, 299_999, "fast_radar_fidelity: the radar comparison's scenes "
            "(200000-200059 published)"),
    SeedSet("fast_radar_slam", 300_000, 399_999, "fast_radar_fidelity: the SLAM comparison's seeds "
            "(300000-300019 published)"),
)
_NAMED = {s.name: s for s in (*LEDGER, *SCENE_SETS)}

#: the sets the project's policies were trained near, chosen, tuned or judged on before the lane rule trial, as
#: (first, last): what that trial's ``overlap`` names (its own test set, ``lane_rule_test``, it reruns on; its check
#: now refuses every set of the ledger but its own, ``heldout_2000`` too)
#: the sets the ledger added after the trial (later studies' sets) are not among them
USED_SEEDS = tuple((BY_NAME[n].first, BY_NAME[n].last) for n in (
    "training", "policies_table", "rl_finetune_heldout", "shield_validation", "lane_analysis", "rl_confirm_test",
    "rl_confirm_validation", "training_eval"))


def seed_set(name: str) -> SeedSet:
    """The set ``name`` of the ledger or of :data:`SCENE_SETS`; ``ValueError`` naming the known sets otherwise."""
    if name not in _NAMED:
        raise ValueError(f"seed set {name!r} is not in the ledger (rhs_studies/kit/seeds.py): known {sorted(_NAMED)}")
    return _NAMED[name]


def first(name: str, offset: int = 0) -> int:
    """The first seed of the named set (:func:`seed_set`), or the seed ``offset`` after it: a study's seed default.

    Args:
        name: a set of :data:`LEDGER` or :data:`SCENE_SETS`.
        offset: seeds after the set's first (a default that starts inside a set), ``0 <= offset`` and inside it.

    Returns:
        ``seed_set(name).first + offset``.
    """
    s = seed_set(name)
    check_int(f"seed set {name} offset", offset, 0, s.last - s.first)
    return s.first + offset


def overlap(seeds: Iterable[int], ledger: Iterable[SeedSet] = LEDGER, allow: Iterable[str] = ()) -> list[SeedSet]:
    """The sets of ``ledger`` that ``seeds`` touch, except those named in ``allow`` (a study rerunning its own set).

    Args:
        seeds: the episode seeds a study means to drive.
        ledger: the sets to check against (default: every driven set).
        allow: names of sets the caller may drive again (its own).

    Returns:
        The sets touched, in ledger order (empty: the seeds are fresh).
    """
    wanted = sorted(set(seeds))
    allowed = set(allow)
    return [s for s in ledger if s.name not in allowed and any(s.first <= x <= s.last for x in wanted)]


def check_fresh(seeds: list[int], what: str, allow: Iterable[str] = ()) -> None:
    """``ValueError`` when ``seeds`` (named ``what`` in the message) touch a set already driven (:func:`overlap`).

    Args:
        seeds: the episode seeds, at least one.
        what: how the message names them (a flag, a spec field).
        allow: names of sets the caller may drive again.
    """
    touched = overlap(seeds, allow=allow)
    if touched:
        sets = ", ".join(f"{s.name} ({s.first}-{s.last})" for s in touched)
        raise ValueError(f"{what} {min(seeds)}-{max(seeds)} overlap seeds already used: {sets}; choose fresh ones")


def consecutive(first: int, count: int) -> list[int]:
    """``count`` seeds from ``first``, checked (``count`` >= 1)."""
    check_int("seed", first, 0, 2**31 - 1)
    check_int("episodes", count, 1, 10**6)
    return list(range(first, first + count))


__all__ = ["BY_NAME", "LEDGER", "SCENE_SETS", "USED_SEEDS", "SeedSet", "check_fresh", "consecutive", "first", "overlap",
           "seed_set"]
