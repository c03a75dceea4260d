"""An attribute read through to one of its owner's parts: ``url = Delegate[str]("_link")`` says
in one line what a property said in three (``Board.url`` is its link's)."""

from __future__ import annotations

from typing import Generic, TypeVar, overload

T = TypeVar("T")


class Delegate(Generic[T]):
    """A read-only attribute: the same-named attribute of the owner's ``part`` (the name of the
    owner's attribute that holds it), read each time (it may change there)."""

    def __init__(self, part: str, doc: str = "") -> None:
        self.part = part
        self.name = ""
        self.__doc__ = doc

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    @overload
    def __get__(self, obj: None, owner: type | None = None) -> Delegate[T]: ...

    @overload
    def __get__(self, obj: object, owner: type | None = None) -> T: ...

    def __get__(self, obj: object | None, owner: type | None = None) -> Delegate[T] | T:
        if obj is None:
            return self
        value: T = getattr(getattr(obj, self.part), self.name)
        return value

    def __set__(self, obj: object, value: T) -> None:
        raise AttributeError(f"{self.name} is {self.part}'s: read only here")
