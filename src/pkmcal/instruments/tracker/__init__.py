"""Calibration from laser-tracker points (seed 001): the instrument's package.

(Step one of its split: the module moved here whole, as :mod:`.fit`; the next commit splits
it into one module per concept.)
"""

import sys as _sys

from . import fit as _module

# the package is the moved module until the split
_sys.modules[__name__].__dict__.update(
    {k: v for k, v in vars(_module).items() if not k.startswith("__")})
