"""Moved to `mitsonar.inverse.piles` (this old path warns: `mitsonar._moved.MOVED`)."""
from mitsonar._moved import warn
from mitsonar.inverse.piles import *  # noqa: F401,F403
warn(__name__)
