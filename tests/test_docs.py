"""The documentation site covers what the code offers: every registered plugin has a generated
reference section, every public name of the package is in the API reference, and the
electronics table the docs print names exactly the fields the sensor accepts.

(The site itself is built with warnings as errors by ``.ci/run``; these checks need no Sphinx.)
"""
from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import mitsonar
from mitsonar.receiver.electronics import Electronics
from mitsonar.plugins import registered
from mitsonar.plugins.props import table_parameters

DOCS = Path(__file__).resolve().parent.parent / "docs"


def test_every_plugin_has_a_generated_reference_section():
    page = (DOCS / "plugins.rst").read_text()
    documented = re.findall(r"^\.\. mitsonar-plugin:: (\S+)\s*$", page, flags=re.M)
    assert sorted(documented) == sorted(registered())
    assert re.search(r"^\.\. mitsonar-electronics::\s*$", page, flags=re.M)


def test_every_public_name_is_in_the_api_reference():
    page = (DOCS / "api.rst").read_text()
    names = [n for n in mitsonar.__all__ if n != "__version__"]
    missing = [n for n in names if not re.search(rf"\bmitsonar\.{re.escape(n)}\b", page)]
    assert not missing, f"docs/api.rst does not document: {', '.join(missing)}"
    for name in ("hilbertmap.HilbertMap", "hilbertmap.IncrementalHilbertMap", "mitsonar.plots",
                 "mitsonar.bathymetry", "mitsonar.echosounders", "mitsonar.sidescan",
                 "mitsonar.receiver.electronics.Electronics"):
        assert re.search(rf"^\.\. auto\w+:: {re.escape(name)}\s*$", page, flags=re.M), name


def test_electronics_table_names_every_field():
    # The plugin reference prints Electronics' docstring table; the sensor accepts its fields.
    assert table_parameters(Electronics.__doc__) == [f.name for f in dataclasses.fields(Electronics)]


def test_every_page_is_in_a_table_of_contents():
    pages = {p.relative_to(DOCS).with_suffix("").as_posix() for p in DOCS.rglob("*.rst")
             if "_build" not in p.parts}
    listed = {"index"}
    for page in DOCS.rglob("*.rst"):
        if "_build" in page.parts:
            continue
        text = page.read_text()
        for block in re.findall(r"^\.\. toctree::\n((?:[ \t]+.*\n|\n)+)", text, flags=re.M):
            base = page.parent.relative_to(DOCS)
            for entry in re.findall(r"^[ \t]+([\w/]+)\s*$", block, flags=re.M):
                listed.add((base / entry).as_posix())
    assert pages <= listed, f"pages outside every toctree: {sorted(pages - listed)}"


def test_readme_is_a_short_front_page_whose_links_resolve():
    root = DOCS.parent
    readme = (root / "README.md").read_text()
    assert len(readme.splitlines()) < 200
    # the two commands, exactly as the setup documents them
    assert "\nbash scripts/demo.sh\n" in readme and "\nbash scripts/test.sh\n" in readme
    links = [link for link in re.findall(r"\]\(([^)\s]+)\)", readme) if "://" not in link]
    assert links, "the README links to the documentation"
    missing = [link for link in links if not (root / link).exists()]
    assert not missing, f"README links to missing files: {missing}"
    # every top-level page (the changelog page shows CHANGELOG.md, which the README links)
    pages = {p.relative_to(root).as_posix() for p in DOCS.glob("*.rst")} - {"docs/index.rst", "docs/changelog.rst"}
    assert "CHANGELOG.md" in links
    assert pages <= set(links), f"top-level pages the README does not link: {sorted(pages - set(links))}"


def _simple_table_margin_errors(doc: str) -> list:
    """Rows of the RST simple tables in ``doc`` with text in a column margin (docutils then
    fails the documentation build with "Malformed table"): the gaps between the ``====`` runs
    of a table's rules must stay blank in every row, except past the last column."""
    import inspect

    errors, lines = [], inspect.cleandoc(doc or "").splitlines()
    i = 0
    while i < len(lines):
        rule = lines[i]
        if not re.fullmatch(r"=+( +=+)+", rule.strip()) or rule != rule.rstrip():
            i += 1
            continue
        gaps = [m.span() for m in re.finditer(r" +", rule.strip())]
        offset = len(rule) - len(rule.lstrip())
        gaps = [(a + offset, b + offset) for a, b in gaps]
        n_rules, j = 1, i + 1
        while j < len(lines) and n_rules < 3:
            row = lines[j]
            if row.strip() == rule.strip():
                n_rules += 1
            elif row.strip():
                for a, b in gaps:
                    if row[a:b].strip():
                        errors.append(row.strip()[:60])
                        break
            j += 1
        i = j
    return errors


def test_parameter_tables_are_well_formed_rst():
    from mitsonar import plugins

    docs = {name: cls.__doc__ for name, (kind, cls) in plugins.registered().items()}
    docs["Electronics"] = Electronics.__doc__
    bad = {name: rows for name, doc in docs.items() if (rows := _simple_table_margin_errors(doc))}
    assert not bad, f"table rows with text in a column margin: {bad}"
