"""``python -m mitsonar``: the command line (same as the ``mitsonar`` command)."""
import sys

from mitsonar.cli import main

sys.exit(main())
