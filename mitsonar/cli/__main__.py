"""``python -m mitsonar.cli``: the command line."""
import sys

from mitsonar.cli.main import main

sys.exit(main())
