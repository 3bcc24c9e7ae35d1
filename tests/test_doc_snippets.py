"""The Python snippets of the documentation run: README.md's ```python blocks and the
``.. code-block:: python`` blocks of docs/getting_started.rst, docs/gallery.rst and the tutorials.

Every snippet uses only names it defines or imports, or that a snippet above it on the same page
defines (pages are read top to bottom): a snippet with an undefined name fails
`test_snippets_use_only_names_they_define`. The quick ones also run
(`test_snippet_runs`), each in a fresh namespace with the working directory in ``tmp_path``:
a snippet that continues the ones above it runs after them in that namespace. Renders in
snippets are shrunk to `SNIPPET_SPP` paths per ping (``spp=N`` in the text becomes
``spp=SNIPPET_SPP``: what a snippet shows does not depend on the noise). Snippets too slow for
the suite, or that read files a shell command above them writes, are listed in `NOT_RUN`, each
with its reason; they are still checked for names. A snippet that imports mitsonar through a
deprecated path fails.
"""
from __future__ import annotations

import ast
import builtins
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", ROOT / "docs" / "getting_started.rst", ROOT / "docs" / "gallery.rst",
         *sorted((ROOT / "docs" / "tutorials").glob("*.rst"))]
#: paths per ping of every render a snippet runs (the text's ``spp=N`` is replaced)
SNIPPET_SPP = 16


@dataclass
class Snippet:
    page: Path
    line: int           # 1-based line of the snippet's first line of code
    index: int          # its place among the page's snippets
    code: str

    @property
    def key(self) -> str:
        return f"{self.page.relative_to(ROOT).as_posix()}:{self.first_line}"

    @property
    def first_line(self) -> str:
        return next(ln.strip() for ln in self.code.splitlines() if ln.strip())


def _rst_snippets(page: Path) -> list[Snippet]:
    lines = page.read_text().splitlines()
    out, i = [], 0
    while i < len(lines):
        if re.match(r"^\s*\.\. code-block:: python\s*$", lines[i]):
            indent = len(lines[i]) - len(lines[i].lstrip())
            j = i + 1
            while j < len(lines) and (not lines[j].strip() or lines[j].lstrip().startswith(":")):
                j += 1
            start, body = j, []
            while j < len(lines) and (not lines[j].strip() or len(lines[j]) - len(lines[j].lstrip()) > indent):
                body.append(lines[j])
                j += 1
            code = "\n".join(body)
            pad = min(len(ln) - len(ln.lstrip()) for ln in body if ln.strip())
            out.append(Snippet(page, start + 1, len(out), "\n".join(ln[pad:] for ln in body).strip() + "\n"))
            i = j
        else:
            i += 1
    return out


def _markdown_snippets(page: Path) -> list[Snippet]:
    text = page.read_text()
    out = []
    for m in re.finditer(r"^```python\n(.*?)^```", text, flags=re.M | re.S):
        out.append(Snippet(page, text[:m.start(1)].count("\n") + 1, len(out), m.group(1)))
    return out


SNIPPETS = [s for page in PAGES
            for s in (_markdown_snippets(page) if page.suffix == ".md" else _rst_snippets(page))]

#: Snippets the suite does not run (page, then the snippet's first line of code), with the reason;
#: the suite runs in well under a minute without them.
NOT_RUN = {
    "docs/tutorials/datasets.rst:import mitsonar": "reads the dataset the shell command above it renders",
    "docs/tutorials/gradients.rst:import drjit as dr, mitsuba as mi":
        "runs 40 optimiser steps, each a render and its gradient (7 s at the shrunk spp)",
    "docs/tutorials/sidescan.rst:import mitsonar": "renders the wreck's whole side-scan survey (8 s at the shrunk spp)",
    "docs/tutorials/mapping.rst:import numpy as np": "fits a Hilbert map to a full box scan (about 40 s on 2 cores)",
    "docs/tutorials/mapping.rst:from hilbertmap import IncrementalHilbertMap":
        "renders and maps a whole survey of the rocky slope (minutes)",
    "docs/gallery.rst:from hilbertmap import HilbertMap": "fits a Hilbert map to a full box scan (about 40 s on 2 cores)",
    "docs/tutorials/your_world.rst:import laspy": "reads the soundings the bathymetry command above it writes",
}


def _bound(tree) -> set:
    """Every name the code binds anywhere (assignments, imports, loops, with, def, class, ...)."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Name) and isinstance(node.ctx, (ast.Store, ast.Del)):
            names.add(node.id)
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names.update((a.asname or a.name).split(".")[0] for a in node.names)
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.arg):
            names.add(node.arg)
        elif isinstance(node, ast.ExceptHandler) and node.name:
            names.add(node.name)
    return names


def undefined(code: str, known: set) -> set:
    """Names ``code`` reads that neither it, ``known`` nor Python's builtins define."""
    tree = ast.parse(code)
    used = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Load)}
    return used - _bound(tree) - known - set(dir(builtins))


def defined_before(snippet: Snippet) -> set:
    """The names the snippets above ``snippet`` on its page define."""
    names = set()
    for s in SNIPPETS:
        if s.page == snippet.page and s.index < snippet.index:
            names |= _bound(ast.parse(s.code))
    return names


def _prelude(snippet: Snippet) -> list[Snippet]:
    """The snippets above ``snippet`` on its page it needs: none when it stands alone."""
    if not undefined(snippet.code, set()):
        return []
    return [s for s in SNIPPETS if s.page == snippet.page and s.index < snippet.index]


def test_the_pages_hold_snippets():
    pages = {s.page.name for s in SNIPPETS}
    assert {"README.md", "getting_started.rst", "mapping.rst", "survey.rst"} <= pages
    assert all(s.key.split(":", 1)[1] for s in SNIPPETS)
    assert set(NOT_RUN) <= {s.key for s in SNIPPETS}, sorted(set(NOT_RUN) - {s.key for s in SNIPPETS})


@pytest.mark.parametrize("snippet", SNIPPETS, ids=lambda s: f"{s.page.name}:{s.line}")
def test_snippets_use_only_names_they_define(snippet):
    missing = undefined(snippet.code, defined_before(snippet))
    assert not missing, f"{snippet.page.relative_to(ROOT)} line {snippet.line}: undefined {sorted(missing)}"


def _shrunk(code: str) -> str:
    return re.sub(r"\bspp=\d+", f"spp={SNIPPET_SPP}", code)


@pytest.mark.parametrize("snippet", SNIPPETS, ids=lambda s: f"{s.page.name}:{s.line}")
def test_snippet_runs(snippet, tmp_path, monkeypatch):
    chain = _prelude(snippet) + [snippet]
    slow = [s.key for s in chain if s.key in NOT_RUN]
    if slow:
        pytest.skip(f"{slow[0]}: {NOT_RUN[slow[0]]}")
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": "__snippet__"}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DeprecationWarning)
        for s in chain:
            exec(compile(_shrunk(s.code), f"{s.page.relative_to(ROOT)}:{s.line}", "exec"), namespace)
    old = [str(w.message) for w in caught if issubclass(w.category, DeprecationWarning) and "mitsonar" in str(w.message)]
    assert not old, old
