"""One serialization of a protocol step, read from its dataclass fields and their types.

A step's row (tables, checkpoint logs, ensemble records) has one column per field, in the
order of declaration, by the field's type: ``int`` and ``float`` as they are, ``bool`` as 0/1,
a ``Literal`` as its text, a tuple as its items joined with ``;``; a field of any other type
(the packing, which a checkpoint frame stores itself) has no column of its own. As numbers
(:func:`as_numbers`, :func:`from_numbers`: a checkpoint frame's log) a ``Literal`` is its index
among the ``Literal``'s choices and a tuple of ``Literal`` choices is a bit set in that order,
so the order of the choices is part of the checkpoint format.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from functools import cache
from typing import TYPE_CHECKING, Any, Literal, TypeVar, get_args, get_origin, get_type_hints

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

Value = float | int | str
Row = Mapping[str, Value]
"""A step's numbers by column, in the order of its table (:func:`as_row`)."""
T = TypeVar("T", bound="DataclassInstance")


@cache
def _types(cls: type) -> dict[str, Any]:
    """The resolved type of each field of the dataclass ``cls``, in declaration order."""
    hints = get_type_hints(cls)
    return {f.name: hints[f.name] for f in dataclasses.fields(cls)}


def _choices(hint: Any) -> tuple[str, ...] | None:
    """The choices of a ``Literal`` type; None for another type."""
    return get_args(hint) if get_origin(hint) is Literal else None


def _item_choices(hint: Any) -> tuple[str, ...] | None:
    """The choices of the items of a ``tuple[Literal[...], ...]``; None for another type."""
    return _choices(get_args(hint)[0]) if get_origin(hint) is tuple else None


def _column(hint: Any, value: Any) -> Value | None:
    """The table cell of a field's ``value``; None for a field without a column."""
    if hint is bool:
        return int(value)
    if hint in (int, float) or _choices(hint) is not None:
        return value
    if get_origin(hint) is tuple:
        return ";".join(value)
    return None


def as_row(step: DataclassInstance, after: Mapping[str, Row] | None = None) -> dict[str, Value]:
    """The columns of ``step``'s fields; ``after[name]``: columns that follow field ``name``'s
    (a field without a column of its own, e.g. a record of measurements, is replaced by them)."""
    following = after or {}
    out: dict[str, Value] = {}
    for name, hint in _types(type(step)).items():
        cell = _column(hint, getattr(step, name))
        if cell is not None:
            out[name] = cell
        out.update(following.get(name, {}))
    return out


def as_numbers(step: DataclassInstance, columns: Row) -> dict[str, float]:
    """``columns`` (``step``'s row) as floats: a ``Literal`` field as its choice's index, a
    tuple of ``Literal`` choices as the bits of the choices present."""
    types = _types(type(step))
    out: dict[str, float] = {}
    for name, cell in columns.items():
        hint = types.get(name)
        if (choices := _choices(hint)) is not None:
            cell = choices.index(getattr(step, name))
        elif (choices := _item_choices(hint)) is not None:
            cell = sum(1 << choices.index(item) for item in getattr(step, name))
        out[name] = float(cell)
    return out


def from_numbers(cls: type[T], number: Callable[[str], float], **given: Any) -> T:
    """The ``cls`` step whose fields are ``given`` or read as ``number(name)`` (as written by
    :func:`as_numbers`); a field of another type than those of a column must be ``given``."""
    values = dict(given)
    for name, hint in _types(cls).items():
        if name in values:
            continue
        if (choice := _decoded(hint, number, name)) is not None:
            values[name] = choice
        elif hint in (bool, int, float):
            values[name] = hint(number(name))
        else:
            raise TypeError(f"{cls.__name__}.{name} ({hint}) is not a number: pass it")
    return cls(**values)


def columns_as_text(cls: type, number: Callable[[str], float]) -> dict[str, str]:
    """The ``Literal`` fields of ``cls`` (and tuples of them) read as ``number(name)`` (as
    written by :func:`as_numbers`) and given as their table text."""
    out: dict[str, str] = {}
    for name, hint in _types(cls).items():
        choice = _decoded(hint, number, name)
        if choice is not None:
            out[name] = choice if isinstance(choice, str) else ";".join(choice)
    return out


def _decoded(hint: Any, number: Callable[[str], float], name: str) -> str | tuple[str, ...] | None:
    """Field ``name`` read as ``number(name)``: a ``Literal``'s choice, or the choices whose
    bits are set for a tuple of them (:func:`as_numbers`); None for a field of another type."""
    if (choices := _choices(hint)) is not None:
        return choices[int(number(name))]
    if (choices := _item_choices(hint)) is not None:
        bits = int(number(name))
        return tuple(c for k, c in enumerate(choices) if bits >> k & 1)
    return None


def number_names(cls: type) -> frozenset[str]:
    """The fields of ``cls`` that :func:`as_numbers` writes (those with a column)."""
    return frozenset(
        name
        for name, hint in _types(cls).items()
        if hint in (bool, int, float) or _choices(hint) is not None or get_origin(hint) is tuple
    )
