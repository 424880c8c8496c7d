"""The old path of :mod:`agents.policies.features`, kept for saved policies and code written before the subpackages.

``agents.features`` is that module itself (one module object under both names, so its classes unpickle, its names
import and a patched attribute is seen by both): the shipped policy zips pickle their feature extractor as
``agents.features.PointSetExtractor`` (their ``policy_kwargs``), and the hyperparameter files name it
``importlib.import_module('agents.features')``.
"""

import sys
from typing import TYPE_CHECKING

from agents.policies import features as _module

if TYPE_CHECKING:  # the public names, for static type checkers (at run time the module itself stands here)
    from agents.policies.features import *  # noqa: F403

sys.modules[__name__] = _module
