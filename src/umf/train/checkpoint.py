"""Moved to :mod:`umf.checkpoint` (inference, evaluation and training all read it, and
inference should not import training). This name is the same module object."""

import sys

from umf import checkpoint as _checkpoint

sys.modules[__name__] = _checkpoint
