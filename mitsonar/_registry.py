"""A registry of named instances of one base class (the sonar kinds, the beam patterns): the one
implementation of their ``register``/``unregister``. Imports nothing."""
from __future__ import annotations


class Registry:
    """``items``: name -> instance, in registration order. ``base`` the class every entry is an
    instance of; ``a_base`` and ``what`` name it in the refusals (``"a SonarKind"``, ``"sonar kind"``)."""

    def __init__(self, base: type, a_base: str, what: str):
        self.base, self.a_base, self.what = base, a_base, what
        self.items: dict = {}

    def register(self, obj):
        """Make ``obj`` (a subclass of ``base`` or an instance) known by its ``name``; returns it
        (usable as a class decorator). A name already taken is refused."""
        inst = obj() if isinstance(obj, type) else obj
        if not isinstance(inst, self.base) or not isinstance(inst.name, str) or not inst.name:
            raise TypeError(f"register: {obj!r} is not {self.a_base} with a name")
        if inst.name in self.items:
            raise ValueError(f"register: {self.what} {inst.name!r} is already registered")
        self.items[inst.name] = inst
        return obj

    def unregister(self, name: str) -> None:
        """Forget the entry called ``name`` (for tests that register a toy one)."""
        self.items.pop(name, None)
