"""Moved to `mitsonar.products.raydiagram` (this old path warns: `mitsonar._moved.MOVED`)."""
from mitsonar._moved import warn
from mitsonar.products.raydiagram import *  # noqa: F401,F403
warn(__name__)
