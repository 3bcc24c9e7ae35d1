"""What differs between the releases of the dependencies that pyproject.toml allows.

`trapezoid`: the trapezoid rule, ``numpy.trapezoid`` from NumPy 2.0 and ``numpy.trapz`` before
(NumPy 2.4 removed ``trapz``; 1.26, the floor, and the numpy<2 that arlpy and others pin have only
``trapz``). The same function under either name: ``trapezoid(y, x=None, dx=1.0, axis=-1)``.

NumPy only (the plugins use it). scripts/test_floors.sh runs part of the suite with every runtime
dependency at its floor, and tests/test_floors.py keeps the NumPy-2-only names out of the code.
"""
import numpy as np

__all__ = ["trapezoid"]

trapezoid = getattr(np, "trapezoid", None) or np.trapz
