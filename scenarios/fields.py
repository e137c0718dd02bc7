"""Field checks shared by the data types, measurement files and experiment files.

Every check takes a value and its ``path``, the key a reader would fix (``noise.toa_s``,
``samples[2].toa_s``, ``sweep.values[1]``, ``trials``), and returns the value converted, or
raises a ``ValueError`` whose message starts with the path and says what is expected.

Arrays: :func:`frozen_array` (a read-only copy of the right shape, every entry finite) and
:func:`check_magnitude` (every entry within a limit); their messages name the entry
(``position_m[3]``, ``toa_s[2][5]``, :func:`entry_path`).

Two kinds of number: :func:`finite` and :func:`positive_finite` take whatever ``float()``
takes (the data types, built in Python); :func:`number` takes only a real number as a file
writes it, not a boolean and not a string (measurement and experiment files).

:class:`FrozenDict` and :func:`frozen_table` keep a table of options (estimator or planner
keyword arguments, fixed sweep values) immutable and hashable; :func:`thaw` gives it back as
plain ``dict`` and ``list``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

REAL_TYPES = (int, float, np.integer, np.floating)
"""The types :func:`number` accepts (``bool`` excepted)."""

FRAME_LIMIT = 2**31
"""Frame indices are whole numbers in ``[0, FRAME_LIMIT)``: they fit a 32-bit signed integer,
whatever stores them (numpy, SQLite, a CSV reader), and no flight has two billion frames."""

MAX_COORDINATE_M = 1e9
"""Largest ``|x|``, ``|y|``, ``|z|`` of a UAV position, of the emitter and its height, and of
the terrain's heights and centre (:mod:`scenarios.terrain`), metres; ``scenarios.types`` names
it too."""


# --------------------------------------------------------------------------------------------
# numbers and text
# --------------------------------------------------------------------------------------------


def finite(value: float, name: str) -> float:
    """Return ``value`` as a float if it is finite, else raise naming ``name``."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number, got {value!r}") from None
    if not math.isfinite(number):
        raise ValueError(f"{name}: must be finite, got {value!r}")
    return number


def positive_finite(value: float, name: str) -> float:
    """Return ``value`` as a float if it is finite and > 0, else raise naming ``name``."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a positive number, got {value!r}") from None
    if not math.isfinite(number) or number <= 0.0:
        raise ValueError(f"{name}: must be finite and > 0, got {value!r}")
    return number


def bounded(value: float, name: str, low: float, high: float, unit: str, fix: str) -> float:
    """Return ``value`` as a float if it is finite and in ``[low, high]``, else raise naming
    ``name``; ``fix`` ends the message (what to check or change)."""
    number = finite(value, name)
    if not low <= number <= high:
        raise ValueError(f"{name}: {number:g} {unit} is outside [{low:g}, {high:g}] {unit}; {fix}")
    return number


def frame_index(value: Any, path: str) -> int:
    """A frame index: a whole number in ``[0, FRAME_LIMIT)`` as an int (``3.0`` is accepted)."""
    whole_value = (
        not isinstance(value, bool)
        and isinstance(value, REAL_TYPES)
        and (not isinstance(value, float | np.floating) or math.isfinite(value))
        and value == int(value)
    )
    if not whole_value or value < 0:
        raise ValueError(f"{path}: expected a whole number >= 0, got {_short(value)}")
    if int(value) >= FRAME_LIMIT:
        raise ValueError(
            f"{path}: frame {_short(value)} is too large; number the frames 0, 1, 2, ... "
            f"(below 2^31 = {FRAME_LIMIT})"
        )
    return int(value)


def _short(value: Any) -> str:
    """``repr(value)``, or its order of magnitude for an integer too long to print."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10**20:
        return f"an integer of {value.bit_length()} bits (about 2^{value.bit_length() - 1})"
    return repr(value)


def number(value: Any, path: str, *, describe: Callable[[Any], str] = repr, fix: str = "") -> float:
    """A finite real number (not a bool, not a string) as a float.

    ``describe`` words a value of the wrong type in the message (default ``repr``); ``fix``
    is appended to the message about a non-finite number.
    """
    if isinstance(value, bool) or not isinstance(value, REAL_TYPES):
        raise ValueError(f"{path}: expected a number, got {describe(value)}")
    try:
        result = float(value)
    except OverflowError:
        raise ValueError(f"{path}: too large for a float (above 1.8e308)") from None
    if not math.isfinite(result):
        raise ValueError(f"{path}: must be finite, got {value!r}{fix}")
    return result


def whole(value: Any, path: str, *, minimum: int) -> int:
    """A whole number ``>= minimum`` as an int; an integral float (``3.0``) is accepted."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        else:
            raise ValueError(f"{path}: expected a whole number >= {minimum}, got {value!r}")
    if value < minimum:
        raise ValueError(f"{path}: must be a whole number >= {minimum}, got {value!r}")
    return int(value)


def text(value: Any, path: str, *, allow_empty: bool = False) -> str:
    """A string, non-empty unless ``allow_empty``."""
    if not isinstance(value, str) or (not value and not allow_empty):
        raise ValueError(f"{path}: expected a non-empty string, got {value!r}")
    return value


def number_list(value: Any, path: str) -> Sequence[Any]:
    """``value`` if it is a list, tuple or array, not a string.

    The items are the caller's to check (with :func:`number` or a parameter's own check), so
    that each message can name the item the way its file does.
    """
    if isinstance(value, str | bytes) or not isinstance(value, Sequence | np.ndarray):
        raise ValueError(f"{path}: expected a list of numbers, got {value!r}")
    return value


# --------------------------------------------------------------------------------------------
# arrays
# --------------------------------------------------------------------------------------------


def frozen_array(
    value: ArrayLike, name: str, shape: tuple[int | None, ...], *, dtype: type = np.float64
) -> NDArray[Any]:
    """Return ``value`` as a read-only array of the given shape, or raise ``ValueError``.

    ``None`` in ``shape`` accepts any length. The message names ``name``, the shape expected
    and the one received, and the first non-finite entry.
    """
    try:
        array = np.array(value, dtype=dtype, copy=True)
    except (TypeError, ValueError, OverflowError) as error:
        raise ValueError(
            f"{name}: expected numbers of shape {_shape_text(shape)} ({error})"
        ) from None
    if array.ndim != len(shape) or any(
        want is not None and got != want for got, want in zip(array.shape, shape, strict=True)
    ):
        raise ValueError(
            f"{name}: expected shape {_shape_text(shape)}, got {array.shape}; "
            "give one value per sample in the same order as the other per-sample fields"
        )
    if array.dtype.kind == "f" and not np.all(np.isfinite(array)):
        index = np.unravel_index(np.argmin(np.isfinite(array)), array.shape)
        raise ValueError(
            f"{name}: entry {tuple(int(i) for i in index)} is {array[index]}; "
            "every value must be finite (drop the sample or mark the modality absent)"
        )
    array.flags.writeable = False
    return array


def _shape_text(shape: tuple[int | None, ...]) -> str:
    names = iter("NMLK")
    return "(" + ", ".join(str(s) if s is not None else next(names) for s in shape) + ")"


def entry_path(name: str, index: Sequence[int]) -> str:
    """``name[i][j]``: the path of an entry of an array, as a message's first word."""
    return name + "".join(f"[{int(i)}]" for i in index)


def vector_text(vector: ArrayLike) -> str:
    """``(1, 2.5, 0)``: a short vector for a message."""
    return "(" + ", ".join(f"{float(v):.6g}" for v in np.asarray(vector).ravel()) + ")"


def check_magnitude(
    array: NDArray[Any],
    name: str,
    limit: float,
    unit: str,
    fix: str,
    *,
    axes: str | None = None,
) -> None:
    """Raise ``ValueError`` naming the first entry of ``array`` with ``|value| > limit``.

    ``axes`` names the last axis's components (``"xyz"``): the message then names the sample
    (``position_m[3]``) and the component; otherwise every index is in the name.
    """
    over = np.abs(array) > limit
    if not over.any():
        return
    index = tuple(int(i) for i in np.argwhere(over)[0])
    value = float(array[index])
    if axes is None:
        what, where = f"{value:g} {unit}", index
    else:
        what, where = f"{axes[index[-1]]} = {value:g} {unit}", index[:-1]
    raise ValueError(f"{entry_path(name, where)}: {what} is beyond ±{limit:g} {unit}; {fix}")


# --------------------------------------------------------------------------------------------
# tables of options
# --------------------------------------------------------------------------------------------


class FrozenDict(Mapping[str, Any]):
    """A read-only, hashable, picklable ``dict``; nested lists become tuples."""

    __slots__ = ("_data",)

    def __init__(self, data: Mapping[str, Any] | None = None) -> None:
        object.__setattr__(self, "_data", {k: _freeze(v) for k, v in dict(data or {}).items()})

    def __getitem__(self, key: str) -> Any:
        return self._data[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._data)

    def __len__(self) -> int:
        return len(self._data)

    def __hash__(self) -> int:
        return hash(frozenset(self._data.items()))

    def __eq__(self, other: object) -> bool:
        if isinstance(other, Mapping):
            return self._data == dict(other.items())
        return NotImplemented

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("FrozenDict is read-only")

    def __reduce__(self) -> tuple[Any, ...]:
        return (FrozenDict, (thaw(self),))

    def __repr__(self) -> str:
        return f"FrozenDict({self._data!r})"


def _freeze(value: Any) -> Any:
    if isinstance(value, Mapping):
        return value if isinstance(value, FrozenDict) else FrozenDict(value)
    if isinstance(value, list | tuple):
        return tuple(_freeze(v) for v in value)
    return value


def thaw(value: Any, *, sequence: type = list) -> Any:
    """A plain-``dict``/``list`` copy of a frozen value (``sequence=tuple`` keeps tuples)."""
    if isinstance(value, Mapping):
        return {k: thaw(v, sequence=sequence) for k, v in value.items()}
    if isinstance(value, tuple | list):
        return sequence(thaw(v, sequence=sequence) for v in value)
    return value


def option_value(value: Any, path: str) -> None:
    """An option: a string, boolean, finite number, or a list or table of them."""
    if isinstance(value, str | bool | int):
        return
    if isinstance(value, float):
        number(value, path)
        return
    if isinstance(value, list | tuple):
        for index, item in enumerate(value):
            option_value(item, f"{path}[{index}]")
        return
    if isinstance(value, Mapping):
        for key, item in value.items():
            option_value(item, f"{path}.{key}")
        return
    raise ValueError(
        f"{path}: expected a string, boolean, number, list or table, got {type(value).__name__}"
    )


def frozen_table(value: Any, path: str) -> FrozenDict:
    """A table of options (names to :func:`option_value` values), frozen."""
    if not isinstance(value, Mapping):
        raise ValueError(f"{path}: expected a table, got {type(value).__name__}")
    for key, item in value.items():
        text(key, path)
        option_value(item, f"{path}.{key}")
    return FrozenDict(value)
