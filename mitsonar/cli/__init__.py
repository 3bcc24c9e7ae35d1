"""The ``mitsonar`` command line: `main` and the shared helpers in `mitsonar.cli.main`, one module
per group of subcommands beside it (``survey``, ``map``, ``bathymetry``, ``export``, ``compare``,
``dataset``, ``serial``: ``virtual-sonar``, ``record``, ``replay``)."""
from mitsonar.cli.main import EXIT_ERROR, EXIT_USAGE, CLIError, build_parser, main

__all__ = ["EXIT_ERROR", "EXIT_USAGE", "CLIError", "build_parser", "main"]


def __getattr__(name):
    # Everything the old single module ``mitsonar.cli`` held (``PLOT_KINDS``, ``make_output_folder``,
    # ...) is still reachable as ``mitsonar.cli.<name>``: it lives in `mitsonar.cli.main`.
    import importlib

    module = importlib.import_module("mitsonar.cli.main")
    try:
        return getattr(module, name)
    except AttributeError:
        raise AttributeError(f"module 'mitsonar.cli' has no attribute {name!r}") from None
