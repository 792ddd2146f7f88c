"""Full poses of a marker on the platform (motion capture, SPEC 2.4): the instrument's package.

(Step one of its split: the module moved here whole, as :mod:`.problems`; the next commit
splits it into one module per concept.)
"""

import sys as _sys

from . import problems as _module

# the package is the moved module until the split
_sys.modules[__name__].__dict__.update(
    {k: v for k, v in vars(_module).items() if not k.startswith("__")})
