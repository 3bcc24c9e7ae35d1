"""The serial heads mitsonar knows, by name: what ``--head NAME`` and a raw log's ``head`` mean.

A head is one folder under ``mitsonar/devices/`` (codec, driver, virtual head, scan assembly)
whose ``registration`` module defines ``HEAD``, an instance of a
`mitsonar.devices.head.Head` subclass; this module knows it by one entry of `BUILTIN`::

    BUILTIN = {"micron": "mitsonar.devices.micron.registration", ...}

`get` imports a head's module the first time it is asked for, so listing the names (``--head``
choices) imports no codec. Heads defined elsewhere (a plugin, a test) call `register`.

The command-line subcommands (`mitsonar.cli.serial`) and `mitsonar.devices.recording.replay`
choose a head only through here: ``get(args.head)`` for ``virtual-sonar``, ``record``, and
`for_log` (the log header's ``head``: `mitsonar.devices.head.Head.log_tag`) for ``replay``.
"""
from __future__ import annotations

import importlib

__all__ = ["BUILTIN", "DEFAULT", "register", "unregister", "get", "names", "heads", "for_log", "for_file"]

#: name -> module defining ``HEAD`` (imported on first use)
BUILTIN = {"micron": "mitsonar.devices.micron.registration",
           "ping360": "mitsonar.devices.ping360.registration",
           "oculus": "mitsonar.devices.oculus.registration"}
#: the head of ``--head``'s default
DEFAULT = "micron"


#: what `register` asks of a head (`mitsonar.devices.head.Head` has it all; this module does not
#: import it: its defaults use `mitsonar.devices.recording`, which asks this module)
_NEEDS = ("name", "log_tag", "options", "serves", "ping_word", "baudrate", "settings", "serve", "record", "replay")

_registered: dict = {}


def register(head, *, replace: bool = False):
    """Make ``head`` known by ``head.name`` (``--head`` choices, `get`, `for_log`); returns it.

    Refuses a name already taken (unless ``replace``) or a log tag another head writes.
    """
    lacks = [a for a in _NEEDS if not hasattr(head, a)]
    if lacks:
        raise TypeError(f"register: a {type(head).__name__} is no mitsonar.devices.head.Head "
                        f"(it lacks {', '.join(lacks)})")
    if not (isinstance(head.name, str) and head.name.isidentifier()):
        raise ValueError(f"register: a head's name must be an identifier, got {head.name!r}")
    if not replace and head.name in names():
        raise ValueError(f"register: head {head.name!r} is already registered")
    for other in heads():
        if other.name != head.name and other.log_tag == head.log_tag:
            raise ValueError(f"register: head {head.name!r} writes the log tag {head.log_tag!r} "
                             f"of head {other.name!r}")
    _registered[head.name] = head
    return head


def unregister(name: str) -> None:
    """Forget a head `register` added (built-in heads stay)."""
    _registered.pop(name, None)


def names() -> tuple[str, ...]:
    """The names of every head, built-in first (imports nothing)."""
    return tuple(BUILTIN) + tuple(n for n in _registered if n not in BUILTIN)


def get(name: str):
    """The head called ``name``; ValueError naming the known ones if there is none."""
    if name in _registered:
        return _registered[name]
    if name not in BUILTIN:
        raise ValueError(f"unknown head {name!r}: known heads are {', '.join(names())}")
    head = importlib.import_module(BUILTIN[name]).HEAD
    if getattr(head, "name", None) != name:
        raise TypeError(f"{BUILTIN[name]}.HEAD is not a head named {name!r}")
    _registered[name] = head
    return head


def heads() -> list:
    """Every head, in the order of `names`."""
    return [get(n) for n in names()]


def for_log(meta: dict, path=None):
    """The head that wrote a raw log, from its header ``meta`` (``head``: the head's ``log_tag``)."""
    tag = meta.get("head")
    for head in heads():
        if head.log_tag == tag:
            return head
    where = f"{path}: " if path is not None else ""
    raise ValueError(f"{where}the log's head {tag!r} is none of the known heads "
                     f"({', '.join(names())})")


def for_file(path):
    """The head whose own log format ``path`` is in (`mitsonar.devices.head.Head.reads_file`:
    an Oculus ``.oculus`` log), or None (then it is a raw log, `for_log`)."""
    for head in heads():
        if head.reads_file(path):
            return head
    return None
