"""The research kit: the studies behind ``results/`` as importable modules, on top of the packages.

Each study is a module with a ``main(argv)`` (run it as ``python -m rhs_studies.NAME`` or,
as every results file's ``provenance.command`` records, ``python scripts/NAME.py``: the
files in ``scripts/`` launch these modules) and, where it writes results, a small-config
``fingerprint()`` that :mod:`rhs_studies.reproduce` checks against ``results/fingerprints.json``.
What several studies share lives in one place here: :mod:`rhs_studies.provenance` (results
records and fingerprints), :mod:`rhs_studies.episodes` (the episode runner and the paper
scene's options), :mod:`rhs_common.stats` (the intervals). The studies read and write the
repository's ``results/``, so they run from a source checkout.

Layering: the top layer, above ``rhs_slam``; it imports the packages, nothing imports it.
"""
