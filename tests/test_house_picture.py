"""The developer notes' picture of the house (docs/developer.rst, drawn at every docs build by
docs/_ext/mitsonar_graph.py from scripts/package_graph.py): its rows put every package above those
it imports, a loop's members in one row, and the same source gives the same SVG bytes."""
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "scripts"))
from package_graph import cycles, layers, package_graph  # noqa: E402


def rows_of(rows):
    return {p: k for k, row in enumerate(rows) for p in row}


def test_layers_put_each_package_above_what_it_imports():
    graph = {"cli": {"sim", "scan"}, "sim": {"scan", "plugins"}, "plugins": {"sim", "checks"},
             "scan": {"checks"}, "checks": set(), "lone": set()}
    rows = layers(graph)
    # plugins and sim are a loop: one row, above everything either imports
    assert rows_of(rows) == {"checks": 0, "lone": 0, "scan": 1, "plugins": 2, "sim": 2, "cli": 3}
    assert sum(map(len, rows)) == len(graph)


def test_the_real_rows_point_every_import_down_or_along_a_loop():
    graph = package_graph()
    row = rows_of(layers(graph))
    assert set(row) == set(graph)
    loop_of = {p: i for i, c in enumerate(cycles(graph)) for p in c}
    for a, imported in graph.items():
        for b in imported:
            same_loop = a in loop_of and loop_of.get(b) == loop_of[a]
            assert row[a] == row[b] if same_loop else row[a] > row[b], (a, b)
    # the rows are as low as they can be: a package above row 0 imports one in the row below it
    for p, k in row.items():
        if k and p not in loop_of:
            assert any(row[b] == k - 1 for b in graph[p]), p


def test_the_drawing_is_the_same_bytes_each_time_and_names_every_package():
    from package_graph import draw, inline, label

    graph = package_graph()
    svg = draw(graph)
    assert svg == draw(graph)
    assert "<dc:date>" not in svg
    for p in graph:
        assert f">{label(p)}<" in svg, p
    assert label("mitsonar.sim") == "sim/" and label("mitsonar.kinds") == "kinds.py"
    page = inline(svg)
    assert page.startswith("<svg") and 'style="width:100%;height:auto"' in page
