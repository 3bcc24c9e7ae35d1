"""Echo-sounder presets: the names of `mitsonar.scenes.echosounders` (with the heads' figures it
takes from `mitsonar.presets.echosounders`), under the public name ``mitsonar.echosounders`` (the
module's docstring is the room's)."""
from mitsonar.presets import echosounders as _figures
from mitsonar.scenes import echosounders as _room
from mitsonar.scenes.echosounders import *  # noqa: F401,F403

__doc__ = _room.__doc__
__all__ = [n for n, v in vars(_room).items()
           if not n.startswith("_") and getattr(v, "__module__", None) == _room.__name__] + list(_figures.__all__)
