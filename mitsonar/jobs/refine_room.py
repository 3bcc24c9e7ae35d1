"""Moved to `mitsonar.inverse.room` (this old path warns: `mitsonar._moved.MOVED`)."""
from mitsonar._moved import warn
from mitsonar.inverse.room import *  # noqa: F401,F403
warn(__name__)
