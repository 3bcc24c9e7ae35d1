"""The side-scan heads the ``sonar`` sensor's ``preset`` names (``kind='sidescan'``): their
published figures and sources are `mitsonar.presets.sidescan` (every sonar model's figures are in
`mitsonar.presets`)."""
from __future__ import annotations

from mitsonar.presets.sidescan import PRESETS

__all__ = ["PRESETS"]
