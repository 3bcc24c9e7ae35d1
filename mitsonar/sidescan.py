"""Side-scan channels, ground range and mosaics: the names of `mitsonar.products.sidescan`, under the
public name ``mitsonar.sidescan`` (the module's docstring is the room's)."""
from mitsonar.products import sidescan as _room
from mitsonar.products.sidescan import *  # noqa: F401,F403

__doc__ = _room.__doc__
__all__ = [n for n, v in vars(_room).items()
           if not n.startswith("_") and getattr(v, "__module__", None) == _room.__name__]
