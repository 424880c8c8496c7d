"""The research kit: what every study uses.

* :mod:`~rhs_studies.kit.runner`: the :class:`~rhs_studies.kit.runner.Study` contract (a frozen options dataclass,
  run, markdown, fingerprint) and the one runner that parses, runs, writes the JSON with provenance and the page;
* :mod:`~rhs_studies.kit.pool`: the one seed-chunked process pool (single-threaded BLAS in its workers);
* :mod:`~rhs_studies.kit.seeds`: the named seed ledger, with the overlap check that keeps a driven set from being
  called fresh;
* :mod:`~rhs_studies.kit.tables`: the driving tables and paired intervals;
* :mod:`~rhs_studies.kit.driving`: the RL arms, their starts and labels, a policy's episodes, the targets;
* :mod:`~rhs_studies.kit.provenance`: the provenance and fingerprints of every results file;
* :mod:`~rhs_studies.kit.episodes`, :mod:`~rhs_studies.kit.scenes`: the episode runner, the paper scene's episode,
  the radar scenes;
* :mod:`~rhs_studies.kit.subprocess_env`: the environment of a study's subprocesses;
* :mod:`~rhs_studies.kit.slam_metrics`, :mod:`~rhs_studies.kit.stats`, :mod:`~rhs_studies.kit.protocol`: the SLAM
  metrics, the RL aggregates, the select-then-test protocol.

A study imports the kit and the packages, never another study (``tests/test_architecture.py``).
"""

__all__: list[str] = []
