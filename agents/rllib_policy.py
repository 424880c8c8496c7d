"""The old path of :mod:`agents.policies.rllib_policy`, kept for saved policies and code written before the subpackages.

``agents.rllib_policy`` is that module itself (one module object under both names, so its classes unpickle, its
names import and a patched attribute is seen by both): saved policies, recorded commands and code written before
name it here.
"""

import sys
from typing import TYPE_CHECKING

from agents.policies import rllib_policy as _module

if TYPE_CHECKING:  # the public names, for static type checkers (at run time the module itself stands here)
    from agents.policies.rllib_policy import *  # noqa: F403

sys.modules[__name__] = _module
