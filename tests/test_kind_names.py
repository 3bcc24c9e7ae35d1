"""``kind`` means the sonar kind (issue 57 item 4): every other thing mitsonar once called a kind
has a name that says what it is (a pulse's ``waveform``, a ``picture``, a plugin ``family``, a
``field_type``, an NMEA ``sentence``, ...). This test reads the code (mitsonar/, plugins/,
hilbertmap/) as syntax and refuses a name that holds the word ``kind`` for something else.

What it looks at: every name, attribute, parameter, keyword argument and function or class name
holding the word (``kind``, ``kinds``, ``*_kind``, ``*Kind*``), and the string ``"kind"`` (or a
compound) as a dict key or subscript. The plain word is the sonar kind where the value bound to it
shows one (`mitsonar.kinds`, ``kind_of``, ``lookup``, a ``.kind``/``.sonar_kind`` read, a sonar
kind's name such as ``"mechanical"``, another such ``kind``); a compound must be one of
`SONAR_WORDS`. Where no value shows it (a parameter, a property), the place must be in
`ALLOWED`, each with its reason. APIs mitsonar does not own are `API_EXCEPTIONS`.
"""
from __future__ import annotations

import ast
import os
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ROOMS = ("mitsonar", "plugins", "hilbertmap")

#: Compound names that mean the sonar kind (or the module of the sonar kinds).
SONAR_WORDS = {
    "sonar_kind",      # a sensor's or Scan's SonarKind instance
    "SonarKind",       # the base class of the sonar kinds
    "kinds",           # the module mitsonar.kinds (``import mitsonar.kinds as kinds``)
    "kind_of",         # mitsonar.kinds.kind_of: the SonarKind of a scan or sensor
    "_xml_kind",       # mitsonar.sim.scene: the SonarKind a <sensor> element names
    "scene_kinds",     # mitsonar.sim.scene: the SonarKind of each sonar of a scene file
    "KINDS",           # mitsonar.kinds.KINDS, the old tuple of the kinds' names
    "_KINDS",          # mitsonar.kinds: the registry of the sonar kinds
}

#: (file, enclosing function or class, word) where ``kind`` means the sonar kind but no value bound
#: there shows it, or a deprecated old name kept for one release (mitsonar._moved.RENAMED).
ALLOWED = {
    # the sonar kinds' registry takes and returns sonar kinds
    ("mitsonar/kinds.py", "register", "kind"),
    # the old name of SonarKind.pictures (until 0.4.0): its property and the subclass hook
    ("mitsonar/kinds.py", "SonarKind.plot_kinds", "plot_kinds"),
    ("mitsonar/kinds.py", "SonarKind.__init_subclass__", "plot_kinds"),
    # the old name of Pulse.waveform and BeamPattern.pattern (until 0.4.0)
    ("mitsonar/signals/pulses.py", "Pulse.kind", "kind"),
    ("plugins/sensors/beam.py", "BeamPattern.kind", "kind"),
}

#: Names of APIs mitsonar does not own that say ``kind``: NumPy's sort algorithm
#: (``np.argsort(..., kind="stable")``) and dtype kind (``a.dtype.kind``).
API_EXCEPTIONS = ("argsort(kind=)", "sort(kind=)", "dtype.kind")

WORD = re.compile(r"(?:^|_)kinds?(?:_|$)|Kind", re.IGNORECASE)


def _sonar_names():
    import mitsonar.kinds as kinds

    return set(kinds.names())


# What a value bound to the plain ``kind`` shows it is the sonar kind by.
SOURCE = re.compile(r"\bkinds\b|\bkind_of\b|\blookup\(|\bsonar_kind\b|\bSonarKind\b|\.kind\b|\bkind\b|"
                    r"['\"]kind['\"]|\b(MECHANICAL|MULTIBEAM|SIDESCAN|VOLUMETRIC)\b")


def has_word(name) -> bool:
    return isinstance(name, str) and bool(WORD.search(name))


class Finder(ast.NodeVisitor):
    """Every use of the word in one module: (line, scope, word, what, ok)."""

    def __init__(self, sonar_names):
        self.scope, self.found, self.sonar_names = [], [], sonar_names

    # ---- where we are
    def _enter(self, node):
        self.scope.append(node.name)
        self.generic_visit(node)
        self.scope.pop()

    def visit_ClassDef(self, node):
        self.scope.append(node.name)
        if has_word(node.name):
            self._word(node, node.name, "class")
        self.scope.pop()
        self._enter(node)

    def visit_FunctionDef(self, node):
        args = node.args
        positional = args.posonlyargs + args.args
        defaults = [None] * (len(positional) - len(args.defaults)) + list(args.defaults)
        self.scope.append(node.name)       # a def and its parameters are found under its qualname
        if has_word(node.name):
            self._word(node, node.name, "function")
        for a, d in list(zip(positional, defaults)) + list(zip(args.kwonlyargs, args.kw_defaults)):
            if has_word(a.arg):        # judged by a default that shows the sonar kind, else ALLOWED
                shown = d is not None and not (isinstance(d, ast.Constant) and d.value is None)
                self._word(a, a.arg, "parameter", value=d, judged=shown)
        self.scope.pop()
        self._enter(node)

    visit_AsyncFunctionDef = visit_FunctionDef

    # ---- the uses
    def _shows_sonar_kind(self, value) -> bool:
        if value is None:
            return False
        if isinstance(value, ast.Constant):
            return value.value in self.sonar_names or value.value is None
        return bool(SOURCE.search(ast.unparse(value)))

    def _word(self, node, word, what, value=None, judged=False, bound=False):
        scope = ".".join(self.scope)
        if word in SONAR_WORDS:        # bound to a value, even these must get a sonar kind
            ok = self._shows_sonar_kind(value) if bound else True
        elif word.lower() == "kind" and judged:
            ok = self._shows_sonar_kind(value)
        else:
            ok = False
        self.found.append((node.lineno, scope, word, what, ok))

    def _targets(self, target, value):
        """The names an assignment binds, each with the value it gets (element-wise for tuples)."""
        if isinstance(target, (ast.Tuple, ast.List)):
            values = value.elts if isinstance(value, (ast.Tuple, ast.List)) and len(value.elts) == len(target.elts) \
                else [value] * len(target.elts)
            for t, v in zip(target.elts, values):
                yield from self._targets(t, v)
        elif isinstance(target, ast.Name):
            yield target, target.id, value
        elif isinstance(target, ast.Attribute):
            yield target, target.attr, value
        elif isinstance(target, ast.Subscript) and isinstance(target.slice, ast.Constant):
            yield target.slice, target.slice.value, value     # ``d["kind"] = value``

    def _bind(self, target, value, what):
        for node, name, v in self._targets(target, value):
            if has_word(name):
                self._word(node, name, what, value=v, judged=True, bound=True)

    def visit_Assign(self, node):
        for t in node.targets:
            self._bind(t, node.value, "assignment")
        self._skip_targets(node.targets)
        self.visit(node.value)

    def visit_AnnAssign(self, node):
        if node.value is None:      # a field declared without a value: its annotation shows it
            for n, name, _ in self._targets(node.target, None):
                if has_word(name):
                    self._word(n, name, "field", value=node.annotation, judged=True)
        else:
            self._bind(node.target, node.value, "assignment")
            self.visit(node.value)
        self._skip_targets([node.target])

    def visit_For(self, node):
        self._bind(node.target, node.iter, "loop variable")
        self._skip_targets([node.target])
        self.visit(node.iter)
        for n in node.body + node.orelse:
            self.visit(n)

    def visit_comprehension(self, node):
        self._bind(node.target, node.iter, "loop variable")
        self._skip_targets([node.target])
        self.visit(node.iter)
        for n in node.ifs:
            self.visit(n)

    def _skip_targets(self, targets):
        """Visit what an assignment's targets read (``a[i].b = ...``: ``a``, ``i``), not the names
        it binds (judged with their value)."""
        for t in targets:
            if isinstance(t, (ast.Tuple, ast.List)):
                self._skip_targets(t.elts)
            elif isinstance(t, ast.Attribute):
                self.visit(t.value)
            elif isinstance(t, ast.Subscript):
                self.visit(t.value)
                if not (isinstance(t.slice, ast.Constant) and has_word(t.slice.value)):
                    self.visit(t.slice)

    def visit_Name(self, node):
        if has_word(node.id):       # a read: a use of a name bound (and judged) elsewhere
            self._word(node, node.id, "name", value=node, judged=True)

    def visit_Attribute(self, node):
        if has_word(node.attr):
            if node.attr == "kind" and ast.unparse(node.value).endswith("dtype"):
                pass                 # numpy's dtype.kind (API_EXCEPTIONS)
            else:                    # reading an attribute defined (and judged) elsewhere
                self._word(node, node.attr, "attribute", value=node, judged=True)
        self.visit(node.value)

    def visit_Call(self, node):
        func = ast.unparse(node.func)
        for k in node.keywords:
            if has_word(k.arg):
                if k.arg == "kind" and func.split(".")[-1] in ("argsort", "sort"):
                    continue         # numpy's sort algorithm (API_EXCEPTIONS)
                self._word(k, k.arg, "keyword argument", value=k.value, judged=True)
        self.generic_visit(node)

    def visit_Dict(self, node):
        for k, v in zip(node.keys, node.values):
            # a key that is a name (a field, a setting, an XML parameter), not a table's text
            if isinstance(k, ast.Constant) and isinstance(k.value, str) and k.value.isidentifier() \
                    and has_word(k.value):
                self._word(k, k.value, "dict key", value=v, judged=True)
        self.generic_visit(node)

    def visit_Subscript(self, node):
        s = node.slice
        if isinstance(s, ast.Constant) and has_word(s.value):
            self._word(s, s.value, "key", value=node, judged=True)
        self.generic_visit(node)


def uses(source: str, sonar_names=None):
    finder = Finder(_sonar_names() if sonar_names is None else sonar_names)
    finder.visit(ast.parse(source))
    return finder.found


def refused(path: str, source: str, sonar_names=None) -> list:
    return [f"{path}:{line} {word} ({what} in {scope or 'the module'})"
            for line, scope, word, what, ok in uses(source, sonar_names)
            if not ok and (path, scope, word) not in ALLOWED]


def modules():
    for room in ROOMS:
        for folder, _, files in os.walk(ROOT / room):
            for f in sorted(files):
                if f.endswith(".py"):
                    p = Path(folder) / f
                    yield p.relative_to(ROOT).as_posix(), p


@pytest.mark.parametrize("rel", sorted(rel for rel, _ in modules()))
def test_kind_is_the_sonar_kind_only(rel):
    assert refused(rel, (ROOT / rel).read_text(encoding="utf-8")) == []


def test_every_allowance_is_still_used():
    """An allowance whose place no longer says ``kind`` goes from the list."""
    seen = set()
    for rel, path in modules():
        seen |= {(rel, scope, word) for _, scope, word, _, ok in uses(path.read_text(encoding="utf-8"))}
    assert ALLOWED - seen == set()


# ---- the checker itself finds the old meanings (each was in mitsonar before issue 57 item 4) ----
OLD = '''
import numpy as np
import mitsonar.kinds as kinds

class Pulse:
    kind: str                                    # the waveform
    f_start: float

def _got(kind, value):                           # a property type
    return kind

def number(props, name):
    kind, value = props.type(name).name, props.get(name)

def _f(kind, doc):
    return dict(metadata={"kind": kind, "doc": doc})

def check_value(key, value, kind="number"):
    return kind

def parse(fields):
    kind = fields[0][2:]                         # an NMEA sentence
    return kind == "GGA"

PLOT_KINDS = kinds.by_name("plot_kinds")

def plot_kind(sonar_kind, kind=None):
    return kind

def guide_kind(scene):
    return False

def use(scan, order):
    check_value("x", 1, kind="any")
    sonar = kinds.lookup(scan.kind)              # the sonar kind: fine
    kind = kinds.kind_of(scan)                   # fine
    k = {"kind": scan.kind}                      # fine
    return np.argsort(order, kind="stable"), order.dtype.kind   # numpy's: fine
'''


def test_the_checker_finds_the_old_meanings():
    found = refused("old.py", OLD, {"mechanical", "multibeam", "sidescan", "volumetric"})
    lines = {int(f.split(":")[1].split()[0]) for f in found}
    text = OLD.splitlines()
    assert {text[i - 1].strip().split("#")[0].strip() for i in lines} == {
        "kind: str", "def _got(kind, value):", "kind, value = props.type(name).name, props.get(name)",
        "def _f(kind, doc):", 'def check_value(key, value, kind="number"):', "kind = fields[0][2:]",
        'PLOT_KINDS = kinds.by_name("plot_kinds")', "def plot_kind(sonar_kind, kind=None):",
        "def guide_kind(scene):", 'check_value("x", 1, kind="any")'}
