"""The ROS 2 message definitions shipped in ``msg/`` and the schema texts built from them.

An MCAP file of ROS 2 messages (encoding ``ros2msg``) stores, per message type, its definition
with every type it depends on appended after a line of 80 ``=`` and ``MSG: pkg/Type``, as
``ros2 bag record`` writes them; `definition` builds that text from the vendored ``.msg`` files
(see ``msg/README`` for their upstream source).
"""
from __future__ import annotations

import functools
import os
import re

MSG_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "msg")
SEPARATOR = "=" * 80

PRIMITIVES = frozenset(("bool", "byte", "char", "int8", "uint8", "int16", "uint16", "int32", "uint32",
                        "int64", "uint64", "float32", "float64", "string", "wstring"))


def _short(datatype: str) -> str:
    """``pkg/msg/Type`` or ``pkg/Type`` -> ``pkg/Type``."""
    parts = datatype.split("/")
    if len(parts) == 3 and parts[1] == "msg":
        parts = [parts[0], parts[2]]
    if len(parts) != 2 or not all(parts):
        raise ValueError(f"ROS message type {datatype!r}: expected pkg/Type or pkg/msg/Type")
    return "/".join(parts)


@functools.lru_cache(maxsize=None)
def text(datatype: str) -> str:
    """The vendored ``.msg`` text of ``datatype`` (``pkg/Type`` or ``pkg/msg/Type``)."""
    pkg, name = _short(datatype).split("/")
    path = os.path.join(MSG_DIR, f"{pkg}.{name}.msg")
    if not os.path.isfile(path):
        raise ValueError(f"ROS message type {datatype!r}: no definition shipped with mitsonar ({path})")
    with open(path, encoding="utf-8") as fh:
        return fh.read().rstrip("\n") + "\n"


def field_types(datatype: str) -> list:
    """The complex (non-primitive) field types of ``datatype``, as ``pkg/Type``, in order."""
    pkg = _short(datatype).split("/")[0]
    out = []
    for line in text(datatype).splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        if re.match(r"^\S+\s+\w+\s*=", line):
            continue                                   # a constant: "uint8 INT8 = 1"
        words = line.split()
        base = re.sub(r"\[.*\]$", "", words[0])
        base = re.sub(r"<=\d+$", "", base)
        if base in PRIMITIVES:
            continue
        out.append(_short(base) if "/" in base else f"{pkg}/{base}")
    return out


def dependencies(datatype: str) -> list:
    """Every type ``datatype`` depends on, directly or not, each once, depth first."""
    seen, order = {_short(datatype)}, []

    def visit(t):
        for dep in field_types(t):
            if dep not in seen:
                seen.add(dep)
                order.append(dep)
                visit(dep)

    visit(_short(datatype))
    return order


@functools.lru_cache(maxsize=None)
def definition(datatype: str) -> str:
    """The full definition text of ``datatype`` as a ROS 2 MCAP schema holds it."""
    parts = [text(datatype)]
    for dep in dependencies(datatype):
        parts.append(f"{SEPARATOR}\nMSG: {dep}\n{text(dep)}")
    return "".join(parts)
