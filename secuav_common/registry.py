"""One shape for every table of named parts (estimators, attack primitives, runtime switches).

A :class:`Registry` holds the built-ins, registered in order by the package that
owns them, and finds the rest through the one plugin lookup
(:func:`secuav_common.plugins.lookup`): an entry point of its group, imported
only when its name is asked for, or a ``package.module:Attribute`` reference.
``check`` says whether an object is a part of this kind; a plugin that fails it
is reported once and left out, a reference that fails it is a ``PluginError``.

With ``key`` (the name a part gives itself, such as a primitive's ``kind``), a
plugin entry point must carry its own name and a plugin, once found, joins the
table under it, so everything that reads :attr:`Registry.table` sees it (the
profile model reads the primitives' table). Without ``key`` the table stays the
built-ins, and plugins are looked up each time (the estimators: a listing tells
the built-ins from the plugins by the table).

Imports nothing of the project but :mod:`secuav_common.plugins`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Generic, TypeVar

from secuav_common import plugins

T = TypeVar("T")


def _any(obj: Any, where: str) -> Any:
    return obj


class Registry(Generic[T]):
    """Name -> part of one kind: the built-ins, then the plugins of ``group`` (see the module docstring)."""

    def __init__(
        self,
        what: str,
        group: str | None = None,
        check: Callable[[Any, str], T] = _any,
        key: Callable[[T], str] | None = None,
        key_label: str = "name",
    ) -> None:
        self.what = what  # "estimator", "primitive", "switch": the word error messages use
        self.group = group  # the entry-point group its plugins declare (None: built-ins only)
        self.check = check  # (object, where) -> the part; raises plugins.PluginError naming ``where`` if it is not one
        self.key = key
        self.key_label = key_label  # what ``key`` reads, for the message when an entry point's name differs
        self.table: dict[str, T] = {}  # the built-ins in registration order, then the plugins found (with ``key``)
        self._builtin: list[str] = []

    def register(self, name: str, part: T) -> T:
        """Add a built-in; a missing name or one already taken is a ``ValueError`` (a bug in the package)."""
        if not name or name in self.table:
            raise ValueError(f"{self.what} name {name!r} missing or taken")
        self.table[name] = part
        self._builtin.append(name)
        return part

    def add(self, name: str, part: T) -> T:
        """Add a part that is not built in (a test's, a lab's own) by an explicit call: the same part twice is
        a no-op, another part under a name already taken a ``ValueError``."""
        if self.table.get(name) is part:
            return part
        if not name or name in self.table:
            raise ValueError(f"{self.what} {name!r} is registered twice")
        self.table[name] = part
        return part

    def remove(self, name: str) -> None:
        """Take an added part out again; a built-in stays."""
        if name not in self._builtin:
            self.table.pop(name, None)

    def unregister(self, name: str) -> None:
        """Take a part out again (a test that declared one of its own)."""
        self.table.pop(name, None)
        if name in self._builtin:
            self._builtin.remove(name)

    def builtin_names(self) -> list[str]:
        """The built-ins' names, in registration order (no plugin is looked at)."""
        return list(self._builtin)

    def is_builtin(self, name: str) -> bool:
        return name in self._builtin

    def lookup(self, name: str) -> T | None:
        """The part ``name`` stands for (built-in, plugin or ``module:Attribute``), or None; imports only that
        plugin. A reference that cannot be used raises ``PluginError``."""
        part = self.table.get(name)
        if part is not None or self.group is None:
            return part
        part = plugins.lookup(self.group, name, self.check)
        if part is None or self.key is None:
            return part
        own = self.key(part)
        if not plugins.is_ref(name) and own != name:
            plugins.reject(self.group, name, f"the entry point is named {name!r} but the class's {self.key_label} "
                                             f"is {own!r}")  # fmt: skip
            return None
        self.table[own] = part
        return part

    def names(self) -> list[str]:
        """Every name that may be asked for: the table's, then the plugins' (metadata only, nothing imported)."""
        found = plugins.found(self.group) if self.group is not None else {}
        return [*self.table, *(n for n in found if n not in self.table)]

    def load_all(self) -> dict[str, T]:
        """Every part by name, plugins imported (a listing); those that fail are reported and left out."""
        out: dict[str, T] = {}
        for name in self.names():
            part = self.lookup(name)
            if part is not None:
                out[name] = part
        return out

    def origin(self, name: str) -> tuple[str, str]:
        """(distribution, version) that provides ``name``: a plugin's entry point, else the part's module."""
        entry = plugins.found(self.group).get(name) if self.group is not None else None
        if not self.is_builtin(name) and entry is not None:
            return entry.dist, entry.version
        return plugins.origin(self.lookup(name))
