"""The import graph of mitsonar, its plugins and hilbertmap, built from the source: acyclic, with
hilbertmap independent of mitsonar, and no module over 700 lines (issue "Architecture"). The graph
is built by ``scripts/package_graph.py`` (`import_graph`), which the developer notes draw.

Every import counts as an edge: at module level, inside functions, inside a module ``__getattr__``
and under ``if TYPE_CHECKING``; ``from . import x`` and ``from .x import y`` inside a package's
submodule also import the package itself (Python runs its ``__init__`` first), so they are edges
to it. A package's ``__init__`` importing its own submodules is not an edge (it gathers them).
"""
import ast
import os
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "scripts"))
# the graph's one home, shared with tests/test_package_graph.py and the docs' drawing of it
from package_graph import cycles, import_graph, modules, targets  # noqa: E402

MAX_LINES = 700


def test_the_graph_sees_lazy_imports():
    """The checker itself: imports inside functions and a module __getattr__ are edges."""
    mods, edges = import_graph()
    # render.py imports the plugins inside functions only
    assert "mitsonar.plugins" in edges["mitsonar.sim.render"]
    # a submodule importing a sibling through its package (``from mitsonar.scan import fileformat``)
    # imports both
    assert {"mitsonar.scan", "mitsonar.scan.fileformat"} <= edges["mitsonar.scan.model"]
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == [["a", "b", "c"]]


def test_import_graph_is_acyclic():
    _, edges = import_graph()
    assert cycles(edges) == []


def test_hilbertmap_does_not_import_mitsonar():
    _, edges = import_graph()
    for name, out in edges.items():
        if name.startswith("hilbertmap"):
            assert not [t for t in out if t.startswith("mitsonar")], (name, out)


@pytest.mark.parametrize("name, path", sorted(modules().items()))
def test_no_module_is_over_700_lines(name, path):
    with open(path, encoding="utf-8") as fh:
        n = sum(1 for _ in fh)
    assert n <= MAX_LINES, f"{name} has {n} lines"


def test_submodules_take_only_submodules_from_their_package():
    """``from . import __version__`` (or ``from mitsonar import load_scan``) inside mitsonar makes a
    submodule depend on the package's ``__init__``, which imports the submodules: a cycle the graph
    above cannot show, since a package gathering its submodules is no edge. Only submodules may
    be imported from one's own package."""
    mods = modules()
    bad = []
    for name, path in mods.items():
        if path.endswith("__init__.py"):
            continue
        package = name.rpartition(".")[0]
        with open(path, encoding="utf-8") as fh:
            tree = ast.parse(fh.read(), path)
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                base = targets(name, False, node)[-1]
                if base in mods and mods[base].endswith("__init__.py") and name.startswith(base + "."):
                    bad += [(name, a.name) for a in node.names if f"{base}.{a.name}" not in mods]
    assert bad == []


# What each room of the plugins may use of mitsonar: its helpers below them (value checks, frames,
# the sonar kinds) and the electronics' settings (the sensor reads and checks its electronics
# fields), nothing else (not the Scan, files, render or devices).
PLUGIN_ROOMS = {
    # the sonar sensor and its beam patterns
    "mitsonar.plugins.sensors": {
        "mitsonar._checks", "mitsonar.geometry.frames", "mitsonar.kinds", "mitsonar.receiver.electronics",
        # the size bounds of every setting (one table; it imports only the checks)
        "mitsonar._limits",
        # what differs between the NumPy releases pyproject.toml allows (NumPy only)
        "mitsonar._compat",
        # the kinds' and beam patterns' registry (imports nothing)
        "mitsonar._registry",
        # the receive elements' layout: the sensor reads its XML elements CSV with it (numpy)
        "mitsonar.geometry.elements",
        # the nominal sound speed (the sensor's and the beam patterns' defaults)
        "mitsonar.acoustics.water",
        # the side-scan heads' published figures (the sensor's ``preset``; imports nothing)
        "mitsonar.presets.sidescan"},
    # the acoustic BSDFs: the seabed and material acoustics (NumPy, and scipy.special for the
    # APL-UW model's erfc; nothing of mitsonar beyond each other): acoustic_material's reflection
    # and backscatter tables
    "mitsonar.plugins.bsdfs": {
        "mitsonar._checks", "mitsonar._compat", "mitsonar.acoustics.interface", "mitsonar.acoustics.seabed",
        "mitsonar.acoustics.materials"},
    # the integrators and their paths
    "mitsonar.plugins.integrators": {
        "mitsonar._checks", "mitsonar._limits", "mitsonar.kinds",
        # the sound-speed profile: the integrators read their XML sound_speed_profile with it
        "mitsonar.acoustics.profile"},
    # the helpers the families share: the sensor's water (absorption and sound speed 'auto')
    # and the water as one value (the sensor's defaults)
    "mitsonar.plugins": {"mitsonar._checks", "mitsonar.acoustics.seawater", "mitsonar.acoustics.water",
                         # the table of renamed public names (register_plugin's old keyword)
                         "mitsonar._moved"},
}
# Which families a family's modules may import (besides the shared helpers at the package's
# top): the integrators trace paths from the sensor over the BSDFs; the sensor and the BSDFs
# know nothing of each other or of the integrators.
PLUGIN_FAMILIES = {"mitsonar.plugins.sensors": set(), "mitsonar.plugins.bsdfs": set(),
                   "mitsonar.plugins.integrators": {"mitsonar.plugins.sensors", "mitsonar.plugins.bsdfs"}}


def plugin_room(name):
    """The room of PLUGIN_ROOMS a plugin module belongs to (its family, or the package's top)."""
    return next((room for room in PLUGIN_FAMILIES if name == room or name.startswith(room + ".")), "mitsonar.plugins")


def test_the_plugins_use_only_the_lowest_mitsonar_modules():
    """Data flows scene -> paths -> histogram -> electronics -> Scan -> files, maps, devices: each
    room of the plugins (`PLUGIN_ROOMS`) uses only the helpers of mitsonar listed for it; the
    families import only the families `PLUGIN_FAMILIES` allows, the shared helpers at the top no
    family, and the integrators' path machinery (``integrators.paths``) none of the integrators
    above it."""
    _, edges = import_graph()
    families = [n for n in edges if n.startswith("mitsonar.plugins.") and n.count(".") == 2 and n in PLUGIN_FAMILIES]
    assert sorted(families) == sorted(PLUGIN_FAMILIES)
    for name, out in edges.items():
        if not name.startswith("mitsonar.plugins"):
            continue
        room = plugin_room(name)
        above = {t for t in out if t.startswith("mitsonar") and not t.startswith("mitsonar.plugins")}
        assert above <= PLUGIN_ROOMS[room], (name, above - PLUGIN_ROOMS[room])
        others = {plugin_room(t) for t in out if t.startswith("mitsonar.plugins.")} - {room, "mitsonar.plugins"}
        assert others <= PLUGIN_FAMILIES.get(room, set()), (name, others)
        if name.startswith("mitsonar.plugins.integrators.paths."):
            up = {t for t in out if t.startswith("mitsonar.plugins.integrators.")
                  and not t.startswith("mitsonar.plugins.integrators.paths")}
            assert not up, (name, up)
    allowed = set().union(*PLUGIN_ROOMS.values())
    # and those import nothing of mitsonar's above them (the electronics' scene speckle, its NumPy
    # and Dr.Jit chains and the sonar equation's levels are leaves beside them)
    leaves = {"mitsonar._checks", "mitsonar._limits", "mitsonar._compat", "mitsonar._registry", "mitsonar._moved",
              "mitsonar.receiver.speckle",
              "mitsonar.receiver.devicechain", "mitsonar.backend",
              # the sonar equation's formulas, and the Scan's typed settings and their migrations
              # (the electronics record what they applied: `ElectronicsSettings`)
              "mitsonar.acoustics.levels", "mitsonar.scan.electronics", "mitsonar.scan.meta",
              "mitsonar.scan.migrations",
              "mitsonar.acoustics._checks", "mitsonar.acoustics.seawater", "mitsonar.acoustics.interface",
              "mitsonar.acoustics.seabed", "mitsonar.acoustics.materials", "mitsonar.geometry.elements",
              "mitsonar.acoustics.water",
              # eigenrays and TL (SoundSpeedProfile.eigenrays calls it; it imports only the checks
              # and the interface)
              "mitsonar.acoustics.propagation"}
    for low in (allowed | leaves) - {"mitsonar._checks", "mitsonar.kinds"}:
        assert not {t for t in edges[low] if t.startswith("mitsonar")} - leaves, low
    # the kinds (numpy only) rotate rows with the frames' rotations, and keep their registry in the
    # one shared with the beam patterns (and warn of an old name through the table of renamed ones)
    assert {t for t in edges["mitsonar.kinds"] if t.startswith("mitsonar")} == \
        {"mitsonar.geometry.frames", "mitsonar._registry", "mitsonar._moved"}
    assert {t for t in edges["mitsonar.receiver.speckle"] if t.startswith("mitsonar")} <= {"mitsonar.receiver.devicechain"}
    # the chain asks for the variant mitsonar would choose (`mitsonar.backend`: nothing of mitsonar)
    assert {t for t in edges["mitsonar.receiver.devicechain"] if t.startswith("mitsonar")} <= {"mitsonar.backend"}
    assert not {t for t in edges["mitsonar.backend"] if t.startswith("mitsonar")}


def test_the_presets_are_a_leaf():
    """Every sonar model's published figures (`mitsonar.presets`) import nothing of mitsonar but the
    value checks and the sonar kinds (NumPy-only leaves): the drivers, the scene builders and the
    plugins take figures from there without pulling in the renderer or one another."""
    _, edges = import_graph()
    presets = [m for m in edges if m == "mitsonar.presets" or m.startswith("mitsonar.presets.")]
    assert {"mitsonar.presets.echosounders", "mitsonar.presets.sidescan", "mitsonar.presets.oculus",
            "mitsonar.presets.micron", "mitsonar.presets.ping360", "mitsonar.presets.volumetric"} <= set(presets)
    for m in presets:
        assert {t for t in edges[m] if t.startswith("mitsonar")} <= {"mitsonar._checks", "mitsonar.kinds"}, m


def test_mitsonar_itself_holds_at_most_14_modules():
    """Code lives in packages by role (sim, scan, receiver, geometry, scenes, products, export,
    devices, live, inverse, presets, jobs, cli, ...): the package's own folder keeps only its entry
    points, shared helpers (with the table of moved modules, ``_moved.py``), the public short names
    and the sonar kinds' registry (``kinds.py``), so a newcomer finds a kind, a head or a format by
    its room."""
    top = sorted(f for f in os.listdir(os.path.join(ROOT, "mitsonar")) if f.endswith(".py"))
    assert len(top) <= 14, top


def test_every_subpackage_says_what_it_holds():
    """Each room has a docstring saying its role (what `help()` and the API reference show)."""
    for root, _, files in os.walk(os.path.join(ROOT, "mitsonar")):
        if "__init__.py" in files:
            with open(os.path.join(root, "__init__.py"), encoding="utf-8") as fh:
                assert ast.get_docstring(ast.parse(fh.read())), root


def head_name_comparisons(path, names):
    """``(line, name)`` of every comparison with a head's name (``== "ping360"``, ``in ("micron",
    ...)``, ``case "micron":``) in one file: the if/else on head names the registry replaces."""
    with open(path, encoding="utf-8") as fh:
        tree = ast.parse(fh.read(), path)

    def named(node):
        consts = [node] if isinstance(node, ast.Constant) else \
            node.elts if isinstance(node, (ast.Tuple, ast.List, ast.Set)) else []
        return [c.value for c in consts if isinstance(c, ast.Constant) and c.value in names]

    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Compare):
            for operand in [node.left, *node.comparators]:
                out += [(node.lineno, n) for n in named(operand)]
        elif isinstance(node, ast.MatchValue):
            out += [(node.lineno, n) for n in named(node.value)]
    return out


def test_the_checker_sees_head_name_comparisons(tmp_path):
    f = tmp_path / "m.py"
    f.write_text('if args.head == "ping360":\n    pass\nx = h in ("micron", "other")\n'
                 'match h:\n    case "micron":\n        pass\nhelp = "--head ping360"\n')
    assert head_name_comparisons(str(f), {"micron", "ping360"}) == [(1, "ping360"), (3, "micron"), (5, "micron")]


def test_heads_are_chosen_only_through_the_registry():
    """No code compares a head's name but the head's own folder (``mitsonar/devices/<head>/``)
    and the registry: the command line, recording and replay ask `mitsonar.devices.registry`, so
    adding a head is one folder plus one registry entry (help texts may name heads)."""
    from mitsonar.devices.registry import BUILTIN
    names = set(BUILTIN)
    own = {os.path.join(ROOT, "mitsonar", "devices", n) for n in names}
    bad = []
    for name, path in sorted(modules().items()):
        if path == os.path.join(ROOT, "mitsonar", "devices", "registry.py") or \
                any(path.startswith(folder + os.sep) for folder in own):
            continue
        bad += [(name, line, n) for line, n in head_name_comparisons(path, names)]
    assert bad == []


# ----------------------------------------------------------------------------- sonar kinds
KIND_NAMES = ("mechanical", "multibeam", "sidescan", "volumetric")
KINDS_MODULE = os.path.join(ROOT, "mitsonar", "kinds.py")
# mitsonar.signals' lazy names point into its volumetric module: a module name, no kind.
NOT_KINDS = {os.path.join(ROOT, "mitsonar", "signals", "__init__.py")}


def _docstrings(tree):
    """The string constants that are docstrings (module, class, function)."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                out.add(id(body[0].value))
    return out


def kind_strings(path):
    """(line, text) of each string in the code at ``path`` that names a sonar kind: a constant equal
    to a kind name, or quoting one (``"kind 'sidescan'"``), docstrings aside; and each comparison
    with the kinds' instances (``kinds.MULTIBEAM.name == x``, ``k is kinds.SIDESCAN``)."""
    with open(path, encoding="utf-8") as fh:
        tree = ast.parse(fh.read(), path)
    docs = _docstrings(tree)
    bad = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docs:
            v = node.value
            if any(v == k or f"'{k}'" in v or f'"{k}"' in v for k in KIND_NAMES):
                bad.append((node.lineno, v))
        if isinstance(node, ast.Compare):
            names = {n.attr if isinstance(n, ast.Attribute) else n.id for n in ast.walk(node)
                     if isinstance(n, (ast.Attribute, ast.Name))}
            if names & {k.upper() for k in KIND_NAMES}:
                bad.append((node.lineno, ast.unparse(node)))
    return sorted(bad)


def test_the_checker_finds_kind_strings(tmp_path):
    src = tmp_path / "m.py"
    src.write_text('"""A mechanical head (docstring: fine)."""\n'
                   'def f(scan, kinds):\n'
                   '    """kind \'sidescan\' in a docstring is fine"""\n'
                   '    a = scan.kind == "multibeam"\n'
                   '    b = f"needs kind \'sidescan\', got {scan.kind}"\n'
                   '    c = "a mechanical head"\n'
                   '    return scan.kind == kinds.MECHANICAL.name\n')
    assert [line for line, _ in kind_strings(str(src))] == [4, 5, 7]


@pytest.mark.parametrize("name, path", sorted((n, p) for n, p in modules().items()
                                              if not n.startswith("hilbertmap")))
def test_only_the_kinds_module_names_the_kinds(name, path):
    """Behaviour that differs between sonar kinds lives on the kind classes of
    `mitsonar.kinds`: no other module of mitsonar or its plugins compares a kind string
    (``scan.kind == "multibeam"``) or keeps a table keyed by kind names; they ask the kind."""
    if path == KINDS_MODULE or path in NOT_KINDS:
        return
    assert kind_strings(path) == [], name


def test_a_new_kind_is_accepted_without_editing_other_modules(tmp_path):
    """A toy kind registered in the kinds' registry is a kind of Scan (checked, saved, loaded), with
    its rows, channels and pictures asked of its class, and a kind of the ``sonar`` sensor."""
    import numpy as np

    import mitsonar
    from mitsonar.cli.main import PICTURES, picture_for
    import mitsonar.kinds as kinds

    class Toy(kinds.SonarKind):
        name = "toy"
        row_name = "staves"
        head_overhead = 0.25
        pictures = ("ascan",)

        def ping_times(self, ping_period, pings, n_rows):
            return np.arange(n_rows) * ping_period * 2.0

    def scan(kind):
        n = 4
        return mitsonar.Scan(intensity=np.ones((n, 3), np.float32), data=np.zeros((n, 3), np.uint8),
                             ranges=np.array([1.0, 2.0, 3.0]), bearings=np.zeros(n),
                             poses=np.broadcast_to(np.eye(4), (n, 4, 4)), range_min=0.5, range_max=3.5, kind=kind)

    with pytest.raises(ValueError, match="'toy' is not allowed"):
        scan("toy")
    kinds.register(Toy)
    try:
        s = scan("toy")
        assert s.sonar_kind.name == "toy" and s.row_name == "staves" and s.channel is None
        s.save(str(tmp_path / "toy.npz"))
        assert mitsonar.load_scan(str(tmp_path / "toy.npz")).kind == "toy"
        assert picture_for("toy") == "ascan" and PICTURES["toy"] == ("ascan",)
        assert "toy" in kinds.names()
        from mitsonar.sim.variant import ensure_variant

        ensure_variant()
        import mitsuba as mi

        sensor = mi.load_dict({"type": "sonar", "kind": "toy", "n_pings": 3, "n_bins": 8, "range_max": 7.5})
        assert sensor.sonar_kind.name == "toy"
        assert sensor.ping_period == pytest.approx(2 * 7.5 / 1500.0 + 0.25)
        assert np.allclose(sensor.ping_times(), [0.0, 2 * sensor.ping_period, 4 * sensor.ping_period])
    finally:
        kinds.unregister("toy")
    with pytest.raises(ValueError, match="'toy' is not allowed"):
        scan("toy")


# ----------------------------------------------------------------------------- beam patterns
PATTERN_NAMES = ("gaussian", "sinc", "uniform", "table")
PATTERNS_MODULE = os.path.join(ROOT, "plugins", "sensors", "beam.py")
# The dataset config's ``uniform`` is a way of drawing a parameter ("uniform", "randint",
# "choice"), not a beam pattern.
NOT_PATTERNS = {os.path.join(ROOT, "mitsonar", "jobs", "dataset", "config.py")}


def pattern_strings(path):
    """(line, code) of each comparison with a beam pattern's name (``beam.kind == "sinc"``,
    ``p in ("gaussian", "uniform")``, ``case "table":``) and each display of two or more pattern
    names (a table keyed by them, ``SEPARABLE = ("gaussian", "uniform", "table")``) in the code at
    ``path``."""
    with open(path, encoding="utf-8") as fh:
        tree = ast.parse(fh.read(), path)

    def names_in(node):
        return [n.value for n in ast.walk(node) if isinstance(n, ast.Constant) and n.value in PATTERN_NAMES]

    bad = []
    for node in ast.walk(tree):
        if isinstance(node, (ast.Compare, ast.MatchValue)) and names_in(node):
            bad.append((node.lineno, ast.unparse(node)))
        elif isinstance(node, (ast.Tuple, ast.List, ast.Set)) and len(names_in(node)) >= 2:
            bad.append((node.lineno, ast.unparse(node)))
        elif isinstance(node, ast.Dict) and len([k for k in node.keys if k is not None and names_in(k)]) >= 2:
            bad.append((node.lineno, ast.unparse(node)))
    return sorted(dict(sorted(bad, reverse=True)).items())   # one finding per line


def test_the_checker_finds_pattern_comparisons(tmp_path):
    src = tmp_path / "m.py"
    src.write_text('"""A gaussian beam (docstring: fine)."""\n'
                   'def f(beam, p):\n'
                   '    a = beam.kind == "sinc"\n'
                   '    b = p in ("gaussian", "uniform")\n'
                   '    c = p.get("beam_pattern", "gaussian")\n'
                   '    match p:\n'
                   '        case "table":\n'
                   '            pass\n'
                   '    d = {"gaussian": 1, "sinc": 2}\n'
                   '    return "use beam_pattern \'gaussian\'"\n')
    assert [line for line, _ in pattern_strings(str(src))] == [3, 4, 7, 9]


@pytest.mark.parametrize("name, path", sorted((n, p) for n, p in modules().items()
                                              if not n.startswith("hilbertmap")))
def test_only_the_pattern_classes_compare_pattern_names(name, path):
    """Behaviour that differs between beam patterns lives on the pattern classes of
    ``plugins/sensors/beam.py`` (`Pattern` and its registered subclasses): no other module compares a
    pattern's name or keeps a table of pattern names; they ask the beam's ``shape``."""
    if path == PATTERNS_MODULE or path in NOT_PATTERNS:
        return
    assert pattern_strings(path) == [], name
