"""The import graph of mitsonar, its plugins and hilbertmap, built from the source (no import of
the code it reads): what ``tests/test_architecture.py`` and ``tests/test_package_graph.py`` check
and what the developer notes draw (``docs/_ext/mitsonar_graph.py``).

Every import counts as an edge: at module level, inside functions, inside a module ``__getattr__``
and under ``if TYPE_CHECKING``; ``from . import x`` and ``from .x import y`` inside a package's
submodule also import the package itself (Python runs its ``__init__`` first), so they are edges
to it. A package's ``__init__`` importing its own submodules is not an edge (it gathers them).

`import_graph` gives the modules' graph, `package_graph` folds it onto the packages
(``mitsonar.<room>``, ``mitsonar.plugins``, ``hilbertmap`` and each module of mitsonar's own folder),
`cycles` finds the loops, `layers` orders the packages for a drawing and `draw` draws them (an SVG
with Matplotlib, no Graphviz, the text kept as text and no date or random id in the file: the same
source gives the same bytes).

    python scripts/package_graph.py     # prints the layers, top (imports the most) first
"""
from __future__ import annotations

import ast
import io
import os
import re

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: source folder -> the name it installs as (pyproject's package-dir)
PACKAGES = {"mitsonar": "mitsonar", "plugins": "mitsonar.plugins", "hilbertmap": "hilbertmap"}


def modules() -> dict:
    """{module name: file path} for every .py file of the three packages."""
    out = {}
    for folder, name in PACKAGES.items():
        for root, _, files in os.walk(os.path.join(ROOT, folder)):
            for f in files:
                if f.endswith(".py"):
                    rel = os.path.relpath(os.path.join(root, f), os.path.join(ROOT, folder))[:-3]
                    parts = [name] + [p for p in rel.split(os.sep) if p != "__init__"]
                    out[".".join(parts)] = os.path.join(root, f)
    return out


def targets(module, is_package, node):
    """The modules one import statement names (longest names first are resolved by the caller)."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    if node.level:
        base = module.split(".") if is_package else module.split(".")[:-1]
        base = base[: len(base) - (node.level - 1)]
        stem = ".".join(base + ([node.module] if node.module else []))
    else:
        stem = node.module
    return [f"{stem}.{a.name}" for a in node.names] + [stem]


def import_graph():
    """``(modules(), {module: set of the modules it imports})``."""
    mods = modules()
    edges = {m: set() for m in mods}
    for name, path in mods.items():
        is_package = path.endswith("__init__.py")
        with open(path, encoding="utf-8") as fh:
            tree = ast.parse(fh.read(), path)
        for node in ast.walk(tree):
            if not isinstance(node, (ast.Import, ast.ImportFrom)):
                continue
            for target in targets(name, is_package, node):
                # the nearest enclosing module we own (``from .x import y``: y may be a name in x)
                while target and target not in mods:
                    target = target.rpartition(".")[0]
                if target and target != name and not (is_package and target.startswith(name + ".")):
                    edges[name].add(target)
    return mods, edges


def cycles(edges) -> list:
    """Strongly connected components with more than one node (Tarjan), each sorted."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def package(module: str) -> str:
    """The package a module belongs to: ``mitsonar.<room>`` (a folder; its subfolders belong to
    it) or a module of mitsonar's own folder, ``mitsonar.plugins``, ``hilbertmap``."""
    parts = module.split(".")
    if parts[0] != "mitsonar" or len(parts) == 1:
        return parts[0]
    return ".".join(parts[:2])


def module_edges() -> dict:
    """{module: modules it imports} of `import_graph`, without the old paths of moved modules
    (`mitsonar._moved.MOVED`: three lines re-exporting the new home, with a warning, until their
    removal release): they are forwarding addresses, not code."""
    from mitsonar._moved import MOVED

    _, edges = import_graph()
    return {k: v for k, v in edges.items() if k not in MOVED}


def package_graph(edges=None) -> dict:
    """{package: set of packages it imports} of `module_edges` (or of ``edges``); imports within a
    package are not edges."""
    if edges is None:
        edges = module_edges()
    out: dict = {}
    for source, targets_ in edges.items():
        out.setdefault(package(source), set())
        for target in targets_:
            a, b = package(source), package(target)
            out.setdefault(b, set())
            if a != b:
                out[a].add(b)
    return out


def layers(graph) -> list:
    """The packages of ``graph`` ({package: set it imports}) in rows for a drawing, bottom first:
    row 0 holds those that import none of the others, and every package sits one row above the
    highest it imports, so each import points down. The packages of one loop (`cycles`) share a
    row (their imports among themselves point sideways). Within a row the packages are ordered to
    shorten the arrows (mean position of what they import and what imports them, a few sweeps),
    ties by name: the same graph gives the same rows."""
    loop_of = {p: tuple(c) for c in cycles(graph) for p in c}
    group = {p: loop_of.get(p, (p,)) for p in graph}
    level: dict = {}

    def height(g):
        if g not in level:
            level[g] = 0                       # a loop's own members are never below it
            below = {group[t] for p in g for t in graph[p]} - {g}
            level[g] = 1 + max((height(b) for b in sorted(below)), default=-1)
        return level[g]

    rows: list = []
    for p in sorted(graph):
        h = height(group[p])
        rows.extend([] for _ in range(h + 1 - len(rows)))
        rows[h].append(p)
    importers = {p: {q for q in graph if p in graph[q]} for p in graph}
    for _ in range(4):                         # downward then upward sweeps of mean positions
        for k in list(range(1, len(rows))) + list(range(len(rows) - 2, -1, -1)):
            # each package's place across its row, 0 .. 1
            where = {p: (i + 0.5) / len(r) for r in rows for i, p in enumerate(r)}

            def mean(p):
                near = sorted(graph[p] | importers[p])
                return sum(where[q] for q in near) / len(near) if near else 0.5

            rows[k].sort(key=lambda p: (round(mean(p), 9), p))
    return rows



#: box colours: a room (folder) of mitsonar, a module of mitsonar's own folder, another package
FILL = {"room": "#dbe9f6", "module": "#f3f3f3", "package": "#e4f2dc"}
LOOP = "#c0392b"


def label(name: str) -> str:
    """What a package is called on the picture: ``sim/`` (a folder of mitsonar), ``kinds.py`` (a
    module of its own folder; ``__init__.py`` is the package ``mitsonar`` itself), ``plugins/``,
    ``hilbertmap/``."""
    if name == "mitsonar":
        return "__init__.py"
    if name == "mitsonar.plugins":
        return "plugins/"
    if not name.startswith("mitsonar."):
        return f"{name}/"
    leaf = name.split(".", 1)[1]
    return f"{leaf}/" if os.path.isdir(os.path.join(ROOT, "mitsonar", leaf)) else f"{leaf}.py"


def _box(name: str) -> str:
    """The fill of a package's box (`FILL`): a room, a module of mitsonar's own folder, another package."""
    if name.startswith("mitsonar.") and name != "mitsonar.plugins":
        return "room" if label(name).endswith("/") else "module"
    return "package"


def draw(graph: dict, fmt: str = "svg"):
    """The SVG text of ``graph`` ({package: set of packages it imports}): one box per package in
    the rows of `package_graph.layers` (bottom row: imports none of the others), one arrow per
    import from the importer down to what it imports; the imports inside a loop in red.
    ``fmt="png"`` gives PNG bytes instead, to look at the picture outside the docs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import FancyArrowPatch, FancyBboxPatch

    rows = layers(graph)
    loops = {p for c in cycles(graph) for p in c}
    wide = max(len(r) for r in rows)
    box_w = 0.2 + 0.09 * max(len(label(p)) for p in graph)      # inches: monospace 10 pt labels
    box_h, gap_x, gap_y = 0.34, 0.25, 0.95
    width = wide * (box_w + gap_x)
    where = {}
    for k, row in enumerate(rows):
        step = width / len(row)
        for i, p in enumerate(row):
            where[p] = ((i + 0.5) * step, k * gap_y)
    height = (len(rows) - 1) * gap_y
    with matplotlib.rc_context({"svg.hashsalt": "mitsonar-package-graph", "svg.fonttype": "none",
                                "font.family": "DejaVu Sans", "font.size": 10}):
        fig = plt.figure(figsize=(width, height + 1.3))
        ax = fig.add_axes([0, 0, 1, 1])
        ax.set_xlim(0, width)
        ax.set_ylim(-0.75, height + 0.55)
        ax.axis("off")
        for a in sorted(graph):
            for b in sorted(graph[a]):
                (xa, ya), (xb, yb) = where[a], where[b]
                sideways = ya == yb
                start = (xa, ya) if sideways else (xa, ya - box_h / 2)
                end = (xb, yb) if sideways else (xb, yb + box_h / 2)
                inside = a in loops and b in loops and sideways
                ax.add_patch(FancyArrowPatch(
                    start, end, arrowstyle="-|>", mutation_scale=7, lw=0.9 if inside else 0.5,
                    color=LOOP if inside else "#6b6b6b", alpha=0.9 if inside else 0.45,
                    # a sideways arrow bends about 0.35 in off its row (half the control offset), whatever its length
                    connectionstyle=f"arc3,rad={0.7 / abs(xb - xa):.4f}" if sideways else "arc3,rad=0.0",
                    shrinkA=9 if sideways else 0, shrinkB=9 if sideways else 0, zorder=1))
        for p, (x, y) in sorted(where.items()):
            ax.add_patch(FancyBboxPatch((x - box_w / 2, y - box_h / 2), box_w, box_h,
                                        boxstyle="round,pad=0.0,rounding_size=0.06", fc=FILL[_box(p)],
                                        ec=LOOP if p in loops else "#555555", lw=1.4 if p in loops else 0.7,
                                        zorder=2))
            ax.text(x, y, label(p), ha="center", va="center", zorder=3, family="monospace")
        notes = ["room/ : a folder of mitsonar", "name.py : a module of mitsonar's own folder",
                 "arrow : imports (at module level or inside a function)"]
        if loops:
            notes.append("red : a loop of packages (tests/test_package_graph.py refuses any)")
        ax.text(0.1, -0.55, "      ".join(notes), ha="left", va="center", fontsize=8, color="#333333")
        out = io.StringIO() if fmt == "svg" else io.BytesIO()
        fig.savefig(out, format=fmt, metadata={"Date": None, "Creator": None} if fmt == "svg" else None)
        plt.close(fig)
    return out.getvalue()


def inline(svg: str) -> str:
    """The SVG as an element of the HTML page: no XML prolog, scaled to the page's width."""
    svg = svg[svg.index("<svg"):]
    head, rest = svg.split(">", 1)
    head = re.sub(r'\s(width|height)="[^"]*"', "", head)
    return f'{head} style="width:100%;height:auto" role="img" aria-label="import graph of the packages">{rest}'


if __name__ == "__main__":
    graph = package_graph()
    for k, row in reversed(list(enumerate(layers(graph)))):
        print(k, " ".join(row))
