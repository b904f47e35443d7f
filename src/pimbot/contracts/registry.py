"""A named registry: the one list of attacks, defenses or learners of its kind."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Generic, TypeVar

from pimbot.contracts import conformance
from pimbot.errors import InvalidParameter

T = TypeVar("T")


class Registry(Generic[T]):
    """Names → entries, in registration order; unknown names fail listing the known ones."""

    def __init__(self, kind: str, field: str):
        self.kind, self.field = kind, field
        self._entries: dict[str, T] = {}

    def register(self, name: str, entry: T, *, replace: bool = False) -> T:
        """Adds `entry` under `name`; a second registration of a name needs `replace`."""
        if not isinstance(name, str) or not name.isidentifier():
            raise ValueError(f"{self.kind} name must be an identifier, got {name!r}")
        if name in self._entries and not replace and self._entries[name] is not entry:
            raise ValueError(f"{self.kind} {name!r} is already registered")
        self._entries[name] = entry
        return entry

    def register_hooked_class(self, cls, base: type, hooks: tuple[str, ...], *, replace=False):
        """Registers a class of hook points under `cls.name`: it must subclass `base`, and
        its code must match what it declares (`conformance.check_hooked_class`: the hook
        points it lists among `hooks` and overrides, `optional_hooks` where it has them,
        its static fields).

        Raises:
            ContractError: one line naming the class's file and line.
        """
        if not (isinstance(cls, type) and issubclass(cls, base)):
            where = conformance.location(cls) if isinstance(cls, type) else repr(cls)
            raise conformance.ContractError(
                f"{where}: {self.kind}s must subclass {base.__module__}.{base.__qualname__}, "
                f"got {cls!r}"
            )
        optional = tuple(getattr(cls, "optional_hooks", ()))
        conformance.check_hooked_class(cls, base, hooks, self.kind, optional)
        return self.register(cls.name, cls, replace=replace)

    def get(self, name: str) -> T:
        if name not in self._entries:
            raise InvalidParameter(
                f"{self.field}: unknown {self.kind} {name!r}; allowed: {', '.join(self.names())}"
            )
        return self._entries[name]

    def names(self) -> list[str]:
        return list(self._entries)

    def __contains__(self, name: object) -> bool:
        return name in self._entries

    def __iter__(self) -> Iterator[str]:
        return iter(self._entries)
