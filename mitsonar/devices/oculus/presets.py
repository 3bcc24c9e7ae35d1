"""Moved to `mitsonar.presets.oculus` (this old path warns: `mitsonar._moved.MOVED`)."""
from mitsonar._moved import warn
from mitsonar.presets.oculus import *  # noqa: F401,F403
warn(__name__)
