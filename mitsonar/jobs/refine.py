"""Moved to `mitsonar.inverse.height_field` (this old path warns: `mitsonar._moved.MOVED`)."""
from mitsonar._moved import warn
from mitsonar.inverse.height_field import *  # noqa: F401,F403
warn(__name__)
