"""`ElectronicsSettings`: the device-electronics settings a `Scan` records (``Scan.electronics``),
typed.

They are what turned the scan's ``intensity`` into its ``data``: the fields of the receiver's
`mitsonar.receiver.electronics.Electronics` (same names, units and order) and ``seed``, the
receiver noise's seed. A field that is None is absent: the receiver's default applies
(``Electronics.from_dict(settings.to_dict())`` fills it). A real head's scan records only what its
replies say (``bit_depth``, ``gain``, ``ad_low``, ``ad_span``). Values are checked for their type
when set (``Scan 'electronics': 'gain': 'high' is not allowed (a number, not NaN, dB)``); their
ranges are the receiver's to check. Keys mitsonar does not know are kept in ``extra``.

`to_dict` gives the keys in the order they were given (`from_dict`), then the fields set later
in declaration order: a file read and written again holds the same bytes. The mapping API of the
dict era (``settings["gain"]``, ``settings.get(...)``, ``{**settings}``) still works for this
release; attributes are the typed way. Files of mitsonar up to 0.2.0 are migrated as they are read
(`mitsonar.scan.migrations`). This module imports nothing from mitsonar beyond `mitsonar.scan`.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from mitsonar.scan.meta import TypedRecord, _f
from mitsonar.scan.migrations import RENAMED_SETTINGS


@dataclass(eq=False, repr=False)
class ElectronicsSettings(TypedRecord):
    """The electronics settings of a `Scan` (all optional; None: absent, the receiver's default).
    Meanings, units and defaults: `mitsonar.receiver.electronics.Electronics`; ``seed``: the
    receiver noise's seed (`render_scan`, `apply_to_scan`); ``extra``: every other key, as given."""

    source_level: float | None = _f("real", "dB re 1 uPa at 1 m")
    receiver_sensitivity: float | None = _f("real", "dB")
    noise_level: float | None = _f("real", "dB re 1 uPa^2/Hz")
    receiver_bandwidth: float | None = _f("real", "Hz")
    tvg: str | None = _f("str", "off, 20log, 30log or 40log")
    tvg_cap: float | None = _f("real", "dB")
    gain: float | None = _f("real", "dB")
    ad_low: float | None = _f("real", "dB")
    ad_span: float | None = _f("real", "dB")
    bit_depth: int | None = _f("whole", "8, 4, 16 or 32")
    pulse_length: float | None = _f("real", "s")
    range_jitter: float | None = _f("real", "m")
    speckle: str | None = _f("str", "off, rayleigh or weibull")
    speckle_shape: float | None = _f("real", "Weibull shape")
    speckle_seed: int | None = _f("whole", "the scene speckle's seed")
    noise_floor: float | None = _f("real", "dB on the A/D scale, -inf for none")
    ringdown: float | None = _f("real", "m")
    ringdown_level: float | None = _f("real", "dB on the A/D scale")
    seed: int | None = _f("whole", "the receiver noise's seed")
    extra: dict[str, Any] = field(default_factory=dict)

    WHERE = "electronics"
    RENAMED = RENAMED_SETTINGS   # the old names of the fields (a class attribute, not a field)

    @classmethod
    def from_dict(cls, d: Mapping | None) -> "ElectronicsSettings":
        """The settings of a dict (a file's, a caller's, `Electronics.to_dict`'s; None: none):
        known keys to their fields, ``bandwidth`` to ``receiver_bandwidth``, others to `extra`;
        `to_dict` keeps the keys' order."""
        if isinstance(d, cls):
            return d
        out = super().from_dict({} if d is None else d)
        object.__setattr__(out, "_order", tuple(cls.RENAMED.get(k, k) if isinstance(k, str) else k
                                                for k in ({} if d is None else d)))
        return out

    def __iter__(self):
        given = getattr(self, "_order", ())
        for key in given:
            if key in self:
                yield key
        for key in super().__iter__():
            if key not in given:
                yield key
