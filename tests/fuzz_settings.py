"""The hypothesis profiles of the property-based suites (``tests/test_fuzz_*.py``).

``rhs`` (the default) keeps the whole fuzz suite under a minute on a 2-core machine (35-40 s measured): few examples
per property, a 10 s deadline per example (a loaded machine must not fail it), derandomized (the same examples
every run), no example database written into the checkout. ``rhs-long``
(``HYPOTHESIS_PROFILE=rhs-long``) runs 20x the examples, for a search before a release.
"""

from __future__ import annotations

import os

from hypothesis import HealthCheck, settings

settings.register_profile("rhs", max_examples=60, deadline=10_000, database=None, derandomize=True,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
settings.register_profile("rhs-long", max_examples=1200, deadline=None, database=None,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "rhs"))
