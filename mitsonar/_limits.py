"""The size bounds of a scene's settings: one table, `LIMITS`, that every check reads.

A ``sonar`` sensor's window and counts, the integrators' counts and the paths per ping are
refused outside these intervals in one line naming where the value came from (the file, the
plugin), the parameter and the interval (`check`)::

    sonar 'range_max': 1e+30 is not allowed (a range > range_min = 0 m, at most 100000 m)

A value inside every bound renders; one outside would render nonsense (``range_max`` 1e30 gave
bins 2e27 m wide, pings 2.6e29 s apart and an all-zero scan) or run out of memory or 32-bit
indices. The bounds, and why (a bound is a physical or a machine limit, not a taste):

``range_min``, ``range_max`` (m): 0 to ``RANGE_MAX_M`` = 100 km. The deepest water is 10.9 km
(Challenger Deep), which a 12 kHz deep-water echo sounder (Kongsberg EM 124) sounds; its outer
beams, 70 deg off nadir there, reach 11 / cos 70 deg = 32 km of slant range. Absorption bounds
the rest: about 1 dB/km at 12 kHz (Francois and Garrison 1982), 200 dB two-way over 100 km, more
than any source level has above the noise; a low-frequency search sonar (1 kHz, 0.06 dB/km)
hears its first convergence zone at 55-65 km. Beyond 100 km nothing a sonar sends returns.

``n_bins``: 1 to 65536 (2^16). Over the widest window (100 km) a bin is then 1.5 m, the range
resolution of a 500 Hz band; over a 12 m window 0.18 mm, finer than any head resolves (a 1 MHz
band: c / 2B = 0.75 mm). The same bound holds for the echo sounders' configured bins.

``n_pings``: 1 to 100000: 500 turns of a mechanical head at 200 steps a turn, or 2.8 h of a
side-scan line at 10 pings/s, in one scan (a scan holds rows x bins float32 values); longer
surveys are several scans (`mitsonar.sim.render_survey`).

``n_beams`` (a multibeam's rows, its ``n_pings``): 1 to 4096. Commercial heads form at most
1024 receive beams a swath (Teledyne Reson T50, R2Sonic 2024; Kongsberg EM 2040 two swaths of
400-800); 4096 leaves a factor 4 for a study of beamforming.

``ping_period`` (s): up to 3600: an hour between pings is a head that is off.

``max_depth``: 1 to 64 surface bounces: every bounce loses the reflection's share (|R|^2 < 1)
and the spreading of its leg, so no echo of 64 bounces is above a head's noise; the integrators
keep one record per bounce per path.

``svp_chords``: 1 to 1024 chords per range window (default 4; the echo ranges do not depend on
them, the hit is timed on the exact arc: `plugins.integrators.paths.refraction`).

``spp``, ``sample_count`` and ``sonar_mlt``'s ``chains``, ``mutations``, ``bootstrap`` (per ping):
up to 2^31 - 1, the paths a 32-bit signed sample index counts (the integrators' lane and sample
indices are 32-bit).

This module imports nothing from mitsonar but `mitsonar._checks`, so every layer may use it.
"""
from __future__ import annotations

from dataclasses import dataclass

from mitsonar._checks import is_number, is_whole, not_allowed


@dataclass(frozen=True)
class Bound:
    """``lo <= value <= hi`` (``whole``: a whole number), described to the user as
    ``"<what>from <lo> to <hi><unit>"``."""

    lo: float
    hi: float
    what: str = ""
    unit: str = ""
    whole: bool = False

    def allowed(self, lo=None, lo_text=None) -> str:
        """The interval in words; ``lo_text`` replaces the lower end (``"a range > range_min = 2 m"``)."""
        if lo_text is not None:
            return f"{lo_text}, at most {_num(self.hi)}{self.unit}"
        start = f"{self.what} from " if self.what else ""
        return f"{start}{_num(self.lo if lo is None else lo)} to {_num(self.hi)}{self.unit}"

    def holds(self, value, lo=None, lo_open=False) -> bool:
        """Whether ``value`` is inside (``lo``: a tighter lower end; ``lo_open``: value > lo)."""
        low = self.lo if lo is None else lo
        if not (is_whole(value) if self.whole else is_number(value)):
            return False
        v = float(value)
        return (v > low if lo_open else v >= low) and v <= self.hi


def _num(x) -> str:
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"


#: The widest range window, m (the module docstring).
RANGE_MAX_M = 100e3
#: The most paths per ping (and chain counts): a signed 32-bit sample index.
PATHS_MAX = 2 ** 31 - 1

#: Every bounded size, by parameter name (the module docstring says why each).
LIMITS = {
    "range_min": Bound(0.0, RANGE_MAX_M, "a range", " m"),
    "range_max": Bound(0.0, RANGE_MAX_M, "a range", " m"),
    "n_bins": Bound(1, 65536, whole=True),
    "n_pings": Bound(1, 100000, whole=True),
    "n_beams": Bound(1, 4096, "a whole number of receive beams", whole=True),
    "ping_period": Bound(0.0, 3600.0, "seconds", " s"),
    "max_depth": Bound(1, 64, "an integer number of surface bounces", whole=True),
    "svp_chords": Bound(1, 1024, "chords per range window, a whole number", whole=True),
    "spp": Bound(1, PATHS_MAX, "a whole number of paths per ping", whole=True),
    "chains": Bound(0, PATHS_MAX, "a whole number of chains per ping (0: automatic)", whole=True),
    "mutations": Bound(0, PATHS_MAX, "a whole number of mutations per chain (0: spend spp)", whole=True),
    "bootstrap": Bound(0, PATHS_MAX, "a whole number of bootstrap paths per ping (0: automatic)", whole=True),
}


def check(where: str, name: str, value, key: str | None = None, lo=None, lo_open=False, lo_text=None,
          suffix: str = ""):
    """``value`` if it lies within ``LIMITS[key or name]`` (``lo``/``lo_open``: a tighter lower
    end, worded ``lo_text``), else the one-line ValueError ``"<where> '<name>': <value> is not
    allowed (<interval><suffix>)"``."""
    bound = LIMITS[key or name]
    if not bound.holds(value, lo, lo_open):
        raise not_allowed(where, name, value, bound.allowed(lo, lo_text) + suffix)
    return value


__all__ = ["Bound", "LIMITS", "PATHS_MAX", "RANGE_MAX_M", "check"]
