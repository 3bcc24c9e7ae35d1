"""Pictures of scans: the names of `mitsonar.products.plots`, under the
public name ``mitsonar.plots`` (the module's docstring is the room's)."""
from mitsonar.products import plots as _room
from mitsonar.products.plots import *  # noqa: F401,F403

__doc__ = _room.__doc__
__all__ = [n for n, v in vars(_room).items()
           if not n.startswith("_") and getattr(v, "__module__", None) == _room.__name__]
