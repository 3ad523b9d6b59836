"""Reading our JSON files: every value checked for its JSON type and range before it becomes a number or
an array, with errors that say which file and which field.

Python's ``json`` gives ``int`` or ``float`` for numbers and ``True == 1``, so an unchecked ``1.5`` or
``true`` where a face index belongs silently becomes face 1, ``2**70`` overflows int64, and ``true``
passes for version 1. :class:`Fields` refuses all of them. The contact file, the hand-pair annotation,
the pairing file and the authors' interchange files are all read through it, so they agree on what is
valid.
"""

from __future__ import annotations

import json
import math
from typing import NoReturn

import numpy as np

_INT64 = 2**63
_NAMES = {str: "a string", int: "an integer", float: "a number", list: "a list", dict: "an object"}


def is_integer(value) -> bool:
    """``value`` is a JSON integer that fits int64 (not a bool, not a float such as ``1.0``)."""
    return type(value) is int and -_INT64 <= value < _INT64


def is_number(value) -> bool:
    """``value`` is a finite JSON number (an int or a float, not a bool)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:  # an integer beyond float range
        return False


def _shown(value) -> str:
    """A value as the file has it (its JSON text, cut at 40 characters): for a wrong scalar or list."""
    try:
        return json.dumps(value)[:40]
    except (TypeError, ValueError):
        return type(value).__name__


class Fields:
    """Checked access to the fields of one JSON object.

    ``where`` names the object in errors: the file (``"pair.json"``), or a path in it
    (``"pair.json: curve 'index'.target"``); a field is named by its dotted path below that
    (``"pair.json: curve 'index'.target.axis_scale must be a number, got null"``). ``error`` is the
    exception class raised, the caller's own (:class:`~geodesics.ContactError`, ...).
    """

    def __init__(
        self, data, where: str, error: type[Exception], what: str = "a JSON object", *, nested: bool = False
    ):
        if not isinstance(data, dict):
            raise error(f"{where} must be {what}, not {_json_type(data)}")
        self.data, self.where, self.error = data, where, error
        self._prefix = f"{where}." if nested else f"{where}: "

    def fail(self, message: str) -> NoReturn:
        """Raise the reader's error about this object."""
        raise self.error(f"{self.where}: {message}")

    def field(self, key: str) -> str:
        """How errors name field ``key`` of this object."""
        return f"{self._prefix}{key}"

    def renamed(self, where: str) -> Fields:
        """The same object, named ``where`` in errors (a list entry once its name is known)."""
        return Fields(self.data, where, self.error, nested=True)

    def __contains__(self, key: str) -> bool:
        """``key`` is present and not null (a null optional field counts as absent, as our writers
        write absent links and pairs)."""
        return self.data.get(key) is not None

    def header(self, format: str, version: int, what: str) -> None:
        """Check the file's ``format`` tag and ``version`` (an integer: ``true`` and ``1.0`` are not 1)."""
        if self.data.get("format") != format:
            self.fail(f"not a {what}: format is {self.data.get('format')!r}, not {format!r}")
        found = self.data.get("version")
        if not is_integer(found) or found != version:
            self.fail(f"version {found!r} is not supported (this build reads {version})")

    def _raise(self, key: str, message: str) -> NoReturn:
        raise self.error(f"{self.field(key)} {message}")

    def value(self, key: str, kind: type, *, optional: bool = False):
        """``data[key]`` of JSON type ``kind`` (``str``, ``int``, ``float`` for any finite number,
        ``list`` or ``dict``); ``None`` when ``optional`` and the field is absent or null."""
        if self.data.get(key) is None and (optional or key not in self.data):
            if optional:
                return None
            self._raise(key, "is missing")
        value = self.data[key]
        ok = {int: is_integer, float: is_number}.get(kind, lambda v: isinstance(v, kind))(value)
        if not ok:
            self._raise(key, f"must be {_NAMES[kind]}, got {_shown(value)}")
        return value

    def string(self, key: str, *, optional: bool = False) -> str | None:
        return self.value(key, str, optional=optional)

    def integer(self, key: str, *, positive: bool = False, optional: bool = False) -> int | None:
        """An integer field (positive when asked)."""
        value = self.value(key, int, optional=optional)
        if value is not None and positive and value <= 0:
            self._raise(key, f"must be a positive integer, got {value}")
        return value

    def number(self, key: str, *, positive: bool = False, optional: bool = False) -> float | None:
        """A finite number field as a float (positive when asked)."""
        value = self.value(key, float, optional=optional)
        if value is not None and positive and value <= 0:
            self._raise(key, f"must be a positive number, got {value}")
        return None if value is None else float(value)

    def list(self, key: str, *, optional: bool = False) -> list | None:
        return self.value(key, list, optional=optional)

    def object(self, key: str, *, optional: bool = False) -> Fields | None:
        """A nested object field, its own fields named below this one's path."""
        value = self.value(key, dict, optional=optional)
        return None if value is None else Fields(value, self.field(key), self.error, nested=True)

    def objects(self, key: str, *, optional: bool = False) -> list[Fields]:
        """A list of objects, the i-th named ``{key}[i]``; an absent optional list is empty."""
        items = self.list(key, optional=optional) or []
        where = self.field(key)
        return [Fields(v, f"{where}[{i}]", self.error, "an object", nested=True) for i, v in enumerate(items)]

    def strings(self, key: str) -> list[str]:
        """A list of strings."""
        values = self.list(key)
        if not all(isinstance(v, str) for v in values):
            self._raise(key, "must be a list of strings")
        return values

    def indices(self, key: str, count: int | None = None) -> np.ndarray:
        """(n,) int64: a flat list of n integers; with ``count``, each an index in ``0..count-1``."""
        values = self.list(key)
        if not all(is_integer(v) for v in values):
            self._raise(key, "must be a list of integer indices")
        out = np.array(values, dtype=np.int64)
        if count is not None and np.any((out < 0) | (out >= count)):
            bad = out[(out < 0) | (out >= count)]
            self._raise(key, f"holds {bad[:5].tolist()}: not indices in 0..{count - 1}")
        return out

    def numbers(self, key: str, shape: tuple[int | None, ...], *, finite: bool = True) -> np.ndarray:
        """A (nested) list of numbers as a float64 array of ``shape`` (``None``: any length); with
        ``finite`` false NaN and infinity pass, for a caller with its own, more telling check."""
        values = self.list(key)
        try:
            out = np.array(values, dtype=np.float64) if _all_numbers(values) else None
        except (ValueError, OverflowError, RecursionError):  # ragged, beyond float range, or too deep
            out = None
        if (
            out is None
            or out.ndim != len(shape)
            or any(n is not None and n != m for n, m in zip(shape, out.shape, strict=True))
            or (finite and not np.all(np.isfinite(out)))
        ):
            kind = "finite numbers" if finite else "numbers"
            if len(shape) == 1 and shape[0] is not None:
                self._raise(key, f"must be {shape[0]} {kind}, got {_shown(values)}")
            dims = " x ".join("n" if n is None else str(n) for n in shape)
            self._raise(key, f"must be an array of {dims} {kind}")
        return out

    def complex(self, key: str) -> np.ndarray:
        """(n,) complex128: a list of n finite ``[real, imaginary]`` pairs (an (n, 2) array in the file)."""
        pairs = self.numbers(key, (None, 2))
        return pairs[:, 0] + 1j * pairs[:, 1]


def _all_numbers(values) -> bool:
    """Whether a (nested) list holds JSON numbers only: ``np.array`` would take booleans and numeric
    strings for numbers. A ragged list holds lists where numbers should be: False. Vectorized: one object
    array, not a Python loop over the elements."""
    return set(map(type, np.array(values, dtype=object).ravel())) <= {int, float}


def _json_type(value) -> str:
    """The JSON type of a value: for an object that is something else (its text could be the whole file)."""
    return {dict: "an object", list: "a list", str: "a string", bool: "a boolean", type(None): "null"}.get(
        type(value), "a number"
    )
