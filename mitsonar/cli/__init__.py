"""The ``mitsonar`` command line: `main` and the shared helpers in `mitsonar.cli.main`, one module
per group of subcommands beside it (``survey``, ``map``, ``bathymetry``, ``export``, ``compare``,
``dataset``, ``serial``: ``virtual-sonar``, ``record``, ``replay``)."""
from mitsonar.cli.main import EXIT_ERROR, EXIT_USAGE, CLIError, build_parser, main

__all__ = ["EXIT_ERROR", "EXIT_USAGE", "CLIError", "build_parser", "main"]

