"""Sphinx configuration of mitsonar's documentation.

Build: ``sphinx-build -W --keep-going -b html docs docs/_build/html`` (what ``.ci/run`` runs).
Nothing is rendered at build time: autodoc and the plugin reference only import the package; the
developer notes' import graph is drawn from the source (``docs/_ext/mitsonar_graph.py``).
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))
sys.path.insert(0, str(HERE.parent))

# The CPU variant, so the plugins import (and autodoc reads them) on a machine without a GPU.
os.environ["MITSONAR_VARIANT"] = "llvm_ad_mono"
import mitsonar  # noqa: E402

mitsonar.set_variant()   # registers the plugins for the variant (import mitsonar does not)

project = "mitsonar"
author = "mitsonar contributors"
copyright = "mitsonar contributors, BSD-3-Clause"
release = mitsonar.__version__
version = release

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "numpydoc",
    "mitsonar_plugins",
    "mitsonar_graph",
]

exclude_patterns = ["_build"]
templates_path = []
html_static_path = ["_static"]
html_theme = "pydata_sphinx_theme"
html_title = f"mitsonar {release}"
html_theme_options = {
    "navbar_align": "left",
    "show_toc_level": 2,
    "navigation_with_keys": False,
    "footer_start": ["copyright"],
    "footer_end": ["sphinx-version"],
}
html_show_sourcelink = False

# `name` in docstrings is a Python object (rendered as code, linked where documented).
default_role = "py:obj"

autodoc_member_order = "bysource"
autodoc_default_options = {"members": True, "undoc-members": False}
autodoc_typehints = "none"
autosummary_generate = False

numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False
