"""Echo-sounder presets: the names of `mitsonar.scenes.echosounders`, under the
public name ``mitsonar.echosounders`` (the module's docstring is the room's)."""
from mitsonar.scenes import echosounders as _room
from mitsonar.scenes.echosounders import *  # noqa: F401,F403

__doc__ = _room.__doc__
__all__ = [n for n, v in vars(_room).items()
           if not n.startswith("_") and getattr(v, "__module__", None) == _room.__name__]
