"""The old path of :mod:`agents.algos.resume`, kept for saved policies and code written before the subpackages.

``agents.resume`` is that module itself (one module object under both names, so its classes unpickle, its names
import and a patched attribute is seen by both): saved policies, recorded commands and code written before name it
here.
"""

import sys
from typing import TYPE_CHECKING

from agents.algos import resume as _module

if TYPE_CHECKING:  # the public names, for static type checkers (at run time the module itself stands here)
    from agents.algos.resume import *  # noqa: F403

sys.modules[__name__] = _module
