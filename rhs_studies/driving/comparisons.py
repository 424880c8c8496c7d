"""Any driving comparison written as a spec file: chosen on validation seeds, tested once on fresh seeds.

A comparison is a YAML file (``rhs_studies/driving/specs/*.yml``, :class:`rhs_studies.kit.protocol.Comparison`):
its candidates (shipped arms or starts, greedy or sampled, behind their saved shield or with fields of it changed),
the reference rows of the choice, the choice rule, the test rows (``$chosen``: the chosen candidate), the paired
block, the targets and the seed sets (ledger names or ``{first, episodes}``). This study runs one with the kit's
select-then-test protocol (:func:`rhs_studies.kit.protocol.run_comparison`), refuses test seeds that touch a set
already driven (:mod:`rhs_studies.kit.seeds`), and writes ``OUT_DIR/<name>.json`` (with provenance) and
``<name>.md``: the choice, one table of the test, the targets. The next comparison is a YAML file, not a module.

    OMP_NUM_THREADS=1 python scripts/compare_policies.py --spec rhs_studies/driving/specs/lane_rule_both_fields.yml
    OMP_NUM_THREADS=1 python scripts/compare_policies.py --spec SPEC.yml --episodes 2 --episode-s 2 --out-dir /tmp/c
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import Any

from rhs_studies.kit.driving import ARMS, LABELS, DriveOptions, check_zips, rl_fingerprint
from rhs_studies.kit.protocol import Comparison, SeedSpec, load_spec, row_driver, run_comparison
from rhs_studies.kit.runner import Study, option, run_study
from rhs_studies.kit.seeds import check_fresh
from rhs_studies.kit.tables import HEADER, RULE, met_text, paired_text, table_row

SPECS = Path(__file__).resolve().parent / "specs"


@dataclass(frozen=True)
class Options(DriveOptions):
    """The spec file and how to drive it (:class:`rhs_studies.kit.driving.DriveOptions`); ``episodes`` /
    ``episode_s`` shorten a run (a smoke test)."""

    spec: Path = option(SPECS / "lane_rule_both_fields.yml", "the comparison's YAML file")
    episodes: int = option(0, "episodes per seed set from each set's first seed (0: the spec's sets)")
    episode_s: float = option(0.0, "episode length in seconds (0: the spec's, else the env's)")

    def __post_init__(self) -> None:
        if self.episodes == 1 or self.episodes < 0:
            raise ValueError("--episodes must be 0 (the spec's sets) or >= 2 (intervals need two episodes)")
        if self.episode_s < 0:
            raise ValueError("--episode-s must be >= 0")
        self.comparison  # noqa: B018 (the spec is read and checked with the options)

    @cached_property
    def comparison(self) -> Comparison:
        """The spec, its seed sets cut to ``episodes`` and its episodes to ``episode_s`` when given."""
        try:
            spec = load_spec(self.spec)
        except (TypeError, OSError) as err:
            raise ValueError(str(err)) from None
        if self.episodes:
            val, test = spec.validation_seeds, spec.test_seeds
            spec = replace(spec, validation_seeds=SeedSpec(first=val.seeds()[0], episodes=self.episodes, allow=val.allow),
                           test_seeds=SeedSpec(first=test.seeds()[0], episodes=self.episodes, allow=test.allow))
        return replace(spec, episode_s=self.episode_s) if self.episode_s else spec

    @property
    def result_name(self) -> str:
        """The results' file stem: the spec's name."""
        return self.comparison.name


def check(opts: Options) -> None:
    """The zips of the spec's arms are present and its test seeds fresh (no ledger set but those it allows)."""
    spec = opts.comparison
    arms = {r.policy for r in (*spec.reference, *spec.candidates, *spec.test) if r.policy in ARMS}
    check_zips(opts.ship_dir, sorted(arms))
    check_fresh(spec.test_seeds.seeds(), f"{opts.spec}: test_seeds", allow=spec.test_seeds.allow)


def run(opts: Options) -> dict[str, Any]:
    """The spec run by the protocol; the result (spec name and title, the choice, the test) without provenance."""
    spec = opts.comparison
    out = run_comparison(spec, row_driver(opts.workers, Path(opts.ship_dir), spec.episode_s), log=spec.name)
    rules = {r.name: {"policy": r.policy, "deterministic": r.deterministic, "shield": dict(r.shield or {})}
             for r in spec.candidates}
    return {"comparison": spec.name, "title": spec.title, "spec": str(opts.spec), "candidates": rules, **out}


def markdown(result: dict[str, Any]) -> str:
    """The choice (one line), the test table paired against the spec's row, and the targets."""
    v, t = result["validation"], result["test"]
    shown = "; ".join(f"{k}: {r['return']['mean']:.1f}, {r['collisions']}/{r['episodes']}" for k, r in v["rows"].items())
    gains = "" if "gains" not in v else " Paired gains: " + "; ".join(f"{k} {paired_text(g)}" for k, g in v["gains"].items()) + "."
    paired_key = next((k for k in t if k.startswith("vs_")), None)
    lines = [f"{result['title'] or result['comparison']}: validation seeds {v['seeds'][0]}-{v['seeds'][-1]} (return, "
             f"collisions): {shown}.{gains} Chosen: **{v['chosen']}**.", "",
             f"Test on seeds {t['seeds'][0]}-{t['seeds'][-1]} ({len(t['seeds'])} episodes, driven once):", "",
             HEADER.format(paired=paired_key or "paired"), RULE]
    lines += [table_row(LABELS.get(k, k), s, (t.get(paired_key) or {}).get(k)) for k, s in t["rows"].items()]
    tg = t.get("targets") or {}
    if tg:
        lines += ["", f"Targets judged on {tg.get('arm')}: {met_text(tg['met'])}."]
    return "\n".join(lines) + "\n"


def fingerprint() -> list[float]:
    """The RL study's: the starts and shipped arms every comparison drives, on one short episode."""
    return rl_fingerprint()


STUDY = Study("", "scripts/compare_policies.py", Options, run, markdown, fingerprint, __doc__, check)


def main(argv: list[str] | None = None) -> int:
    return run_study(STUDY, argv)


if __name__ == "__main__":
    sys.exit(main())
