"""Sphinx directive ``.. mitsonar-plugin:: NAME``: a plugin's reference from its own class.

For a plugin registered for the active variant (``mitsonar.plugins.registered()``: the XML
plugin name ``sonar``, ``acoustic``, ``sonar_tof``, ... and its class),
emits its docstring, which holds the RST parameter table the plugin validates its XML against
(``plugins/props.py: table_parameters`` reads the same table), and then the list
``mitsonar.plugins.parameters(cls)``: every name the plugin accepts. The documentation and the
validation therefore read one source and cannot disagree.

``.. mitsonar-electronics::`` does the same for ``mitsonar.receiver.electronics.Electronics`` (the
electronics fields every ``sonar`` sensor accepts), and ``.. mitsonar-cli::`` prints the
``--help`` of every ``mitsonar`` command from the parser the command line itself uses.
"""
from __future__ import annotations

import dataclasses
import inspect
import sys

from docutils import nodes
from docutils.statemachine import StringList
from sphinx.util.docutils import SphinxDirective
from sphinx.util.nodes import nested_parse_with_titles


def _plugin_entry(name: str):
    from mitsonar import plugins

    found = plugins.registered()
    if name in found:
        return found[name]
    known = ", ".join(found)
    raise ValueError(f"mitsonar-plugin: no plugin {name!r} in mitsonar.plugins.registered() ({known})")


class _RSTDirective(SphinxDirective):
    def _depends_on(self, obj) -> None:
        """Rebuild this page when the source file of ``obj`` changes (Sphinx tracks only .rst)."""
        try:
            self.env.note_dependency(inspect.getsourcefile(obj))
        except TypeError:
            pass

    def _parse(self, lines: list[str]) -> list[nodes.Node]:
        node = nodes.container()
        source = self.get_source_info()[0]
        content = StringList()
        for i, line in enumerate(lines):
            content.append(line, source, i)
        nested_parse_with_titles(self.state, content, node)
        return node.children


class PluginDirective(_RSTDirective):
    """``.. mitsonar-plugin:: sonar``: the plugin's docstring and its accepted parameter names."""

    required_arguments = 1
    has_content = False

    def run(self):
        from mitsonar import plugins

        name = self.arguments[0]
        try:
            kind, cls = _plugin_entry(name)
        except ValueError as exc:
            raise self.error(str(exc)) from None
        names = plugins.parameters(cls)
        self._depends_on(cls)
        lines = [f"*{kind}* ``{name}`` (class ``{cls.__module__}.{cls.__name__}``)", ""]
        lines += inspect.cleandoc(cls.__doc__ or "").splitlines()
        lines += ["", f"Every XML parameter ``{name}`` accepts (any other name is refused, naming the nearest "
                      "of these): " + ", ".join(f"``{n}``" for n in names) + ".", ""]
        return self._parse(lines)


class ElectronicsDirective(_RSTDirective):
    """``.. mitsonar-electronics::``: the fields of ``mitsonar.receiver.electronics.Electronics``."""

    has_content = False

    def run(self):
        from mitsonar.receiver.electronics import Electronics

        self._depends_on(Electronics)
        lines = inspect.cleandoc(Electronics.__doc__ or "").splitlines()
        fields = [f.name for f in dataclasses.fields(Electronics)]
        lines += ["", "Fields: " + ", ".join(f"``{n}``" for n in fields) + ".", ""]
        return self._parse(lines)


class CLIDirective(_RSTDirective):
    """``.. mitsonar-cli::``: one section per ``mitsonar`` command, its ``--help`` verbatim."""

    has_content = False

    def run(self):
        import argparse
        import os

        from mitsonar.cli import build_parser

        old = os.environ.get("COLUMNS")
        os.environ["COLUMNS"] = "100"          # argparse wraps to the terminal: fix it
        try:
            parser = build_parser()
            sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
            out = []
            for module in {m for m in sys.modules if m.startswith("mitsonar.cli")}:
                self._depends_on(sys.modules[module])
            for name, command in sub.choices.items():
                section = nodes.section(ids=[f"cli-{name}"], names=[f"mitsonar {name}"])
                section += nodes.title(text=f"mitsonar {name}")
                section += nodes.literal_block(text=command.format_help().rstrip())
                out.append(section)
        finally:
            if old is None:
                os.environ.pop("COLUMNS", None)
            else:
                os.environ["COLUMNS"] = old
        return out


def setup(app):
    app.add_directive("mitsonar-plugin", PluginDirective)
    app.add_directive("mitsonar-electronics", ElectronicsDirective)
    app.add_directive("mitsonar-cli", CLIDirective)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
