"""The old path of :mod:`agents.algos.rllib`, kept for saved policies and code written before the subpackages.

``agents.rllib`` is that module itself (one module object under both names, so its classes unpickle, its names
import and a patched attribute is seen by both): the RLlib checkpoints written before pickle their RLModule class as
``agents.rllib.PointSetPPOModule``.
"""

import sys
from typing import TYPE_CHECKING

from agents.algos import rllib as _module

if TYPE_CHECKING:  # the public names, for static type checkers (at run time the module itself stands here)
    from agents.algos.rllib import *  # noqa: F403

sys.modules[__name__] = _module
