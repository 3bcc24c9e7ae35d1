"""Moved to `mitsonar.live.outputs` (this old path warns: `mitsonar._moved.MOVED`)."""
from mitsonar._moved import warn
from mitsonar.live.outputs import *  # noqa: F401,F403
warn(__name__)
