"""Loading a plug-in class by ``package.module:Class`` without calling it, and checking the
keyword options it is given against its constructor before it is built.

One loader for every kind of plug-in: planners (:mod:`scenarios.planners.registry`) and
estimators (:mod:`estimators.registry`). Importing a module runs its code, so a plug-in is
imported only when named; what the name refers to is used only if it is a class with the
interface its kind needs (the caller's ``problems``), and nothing of it is called before.
Every error is one line starting with the kind (``estimator``, ``planner``), the field a
caller names.
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import types
import typing
from collections.abc import Mapping
from typing import Any, Literal

import numpy as np

from scenarios.fields import REAL_TYPES

# --------------------------------------------------------------------------------------------
# classes, read without calling them
# --------------------------------------------------------------------------------------------


def import_target(target: str, kind: str) -> Any:
    """The attribute named by ``package.module:attribute`` (the module is imported, run).

    Errors start with ``kind`` (``estimator`` or ``planner``), the field a caller names.
    """
    module_name, _, attribute = target.partition(":")
    if not module_name or not attribute:
        raise ValueError(f"{kind}: {target!r} is not of the form 'package.module:Class'")
    try:
        module = importlib.import_module(module_name)
    except Exception as error:  # a plug-in may fail in any way on import: report, don't crash
        raise ValueError(
            f"{kind}: cannot import {module_name!r} ({type(error).__name__}: {error})"
        ) from None
    try:
        return getattr(module, attribute)
    except AttributeError:
        raise ValueError(f"{kind}: module {module_name!r} has no {attribute!r}") from None


def what_it_is(thing: Any) -> str:
    """``a function``, ``a module``, ``a str object``: what a name refers to, for messages."""
    if inspect.isroutine(thing):
        return "a function"
    if inspect.ismodule(thing):
        return "a module"
    return f"a {type(thing).__name__} object"


def method_takes(cls: type, method: str, keywords: tuple[str, ...]) -> list[str]:
    """Problems of ``cls.method``: missing, or not taking each of ``keywords`` (nothing called)."""
    function = inspect.getattr_static(cls, method, None)
    if isinstance(function, staticmethod | classmethod):
        function = function.__func__
    if not callable(function):
        return [f"the method {method} is missing"]
    try:
        parameters = inspect.signature(function).parameters
    except (TypeError, ValueError):
        return [f"the signature of {method} cannot be read; define it in Python"]
    if any(p.kind is p.VAR_KEYWORD for p in parameters.values()):
        return []
    return [f"{method} must take the keyword {k}" for k in keywords if k not in parameters]


def checked_class(name: str, target: Any, kind: str, problems: Any, interface: str) -> type:
    """``target`` if it is a class without ``problems(target)``; else a one-line error."""
    if not inspect.isclass(target):
        article = "an" if kind[0] in "aeiou" else "a"
        raise ValueError(
            f"{kind}: {name!r} is {what_it_is(target)}, not {article} {kind} class; give "
            f"'package.module:Class' of {interface}"
        )
    found = problems(target)
    if found:
        raise ValueError(
            f"{kind}: {name!r} is the class {target.__qualname__}, which lacks the {kind} "
            f"interface: {'; '.join(found)}; give {interface}"
        )
    return target


# --------------------------------------------------------------------------------------------
# options, checked against the constructor before it runs
# --------------------------------------------------------------------------------------------

UNITS = (
    ("_mps", "m/s"),
    ("_dps", "degrees per second"),
    ("_hz", "hertz"),
    ("_db", "dB"),
    ("_s", "seconds"),
    ("_m", "metres"),
)
"""Unit of an option, from the suffix of its name (the SI names of docs/architecture.md)."""

KEYWORD_KINDS = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)


def check_options(cls: type, options: Mapping[str, Any], owner: str) -> None:
    """Raise ``ValueError`` ``"<option>: <problem and fix>"`` unless ``cls(**options)`` fits.

    Every option must be a named keyword parameter of the constructor (``**kwargs`` accepts
    none: options are introspected), every parameter without a default must be given, and a
    value must match its annotation when the annotation is simple: ``float``, ``int``,
    ``bool``, ``str``, ``None``, ``Literal[...]``, ``tuple[...]`` and unions of them (read with
    :func:`typing.get_type_hints`, from the dataclass fields or ``__init__``). Other
    annotations are left to the constructor. ``owner`` words the class, ``estimator 'cls'``.
    """
    try:
        parameters = inspect.signature(cls).parameters
    except (TypeError, ValueError):
        return  # a constructor without a readable signature: the constructor checks itself
    named = {p.name: p for p in parameters.values() if p.kind in KEYWORD_KINDS}
    unknown = sorted(set(options) - set(named))
    if unknown:
        spread = [p.name for p in parameters.values() if p.kind is p.VAR_KEYWORD]
        note = f" (**{spread[0]} takes none: name each option in the constructor)" if spread else ""
        raise ValueError(
            f"{unknown[0]}: not an option of {owner}; its options: "
            f"{', '.join(sorted(named)) or 'none'}{note}"
        )
    for p in parameters.values():
        if p.default is p.empty and p.kind is p.POSITIONAL_ONLY:
            raise ValueError(
                f"{p.name}: {owner} takes it by position only, which options cannot give; "
                "make it a keyword parameter"
            )
        if p.default is p.empty and p.kind in KEYWORD_KINDS and p.name not in options:
            raise ValueError(f"{p.name}: required by {owner}; add it to the options")
    hints = option_hints(cls)
    for option, value in options.items():
        hint = hints.get(option)
        if hint is not None and not accepts(hint, value):
            raise ValueError(f"{option}: expected {describe(hint, option)}, got {shown(value)}")


def option_hints(cls: type) -> dict[str, Any]:
    """The evaluated annotations of the constructor's parameters (empty when they fail)."""
    owner = cls if dataclasses.is_dataclass(cls) else cls.__init__
    try:
        return typing.get_type_hints(owner)
    except Exception:  # an annotation that does not evaluate is not checked
        return {}


def _items(value: Any) -> list[Any] | None:
    """A list or tuple (or 1-D array) as a list; None for anything else, a string included."""
    if isinstance(value, np.ndarray):
        return value.tolist() if value.ndim == 1 else None
    return list(value) if isinstance(value, list | tuple) else None


def accepts(hint: Any, value: Any) -> bool:
    """``value`` matches the simple annotation ``hint``; True for an annotation not checked."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint is None or hint is type(None):
        return value is None
    if hint is bool:
        return isinstance(value, bool | np.bool_)
    if hint in (int, float):
        numeric = (int, np.integer) if hint is int else REAL_TYPES
        return isinstance(value, numeric) and not isinstance(value, bool | np.bool_)
    if hint is str:
        return isinstance(value, str)
    if origin is Literal:
        return not isinstance(value, np.ndarray | list | tuple | dict) and any(
            isinstance(value, bool) == isinstance(a, bool) and value == a for a in args
        )
    if origin in (typing.Union, types.UnionType):
        return any(accepts(member, value) for member in args)
    if origin is tuple:
        items = _items(value)
        if items is None:
            return False
        if len(args) == 2 and args[1] is Ellipsis:
            return all(accepts(args[0], item) for item in items)
        if not args:
            return True
        return len(items) == len(args) and all(map(accepts, args, items))
    return True  # Any, ArrayLike, a class...: the constructor's to check


def _alternatives(hint: Any, option: str) -> list[str]:
    """The words for what ``hint`` accepts, one per alternative."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    unit = next((f" in {word}" for suffix, word in UNITS if option.endswith(suffix)), "")
    if hint is None or hint is type(None):
        return ["None"]
    if hint is bool:
        return ["true", "false"]
    if origin is Literal:
        return [repr(a) for a in args]
    if origin in (typing.Union, types.UnionType):
        return [word for member in args for word in _alternatives(member, option)]
    if origin is tuple and len(args) == 2 and args[1] is Ellipsis:
        return [f"a list, each {describe(args[0], '')}"]
    if origin is tuple and args:
        if args == (float, float) and unit == " in metres":
            return ["(x, y) in metres"]
        if all(a is float for a in args):
            return [f"a list of {len(args)} numbers{unit}"]
        return [f"a list of {len(args)} values ({', '.join(describe(a, '') for a in args)})"]
    words = {int: "a whole number", float: f"a number{unit}", str: "a string"}
    return [words.get(hint, getattr(hint, "__name__", str(hint)))]


def describe(hint: Any, option: str) -> str:
    """What ``hint`` accepts, in words: ``'all' or 'last'``, ``(x, y) in metres or None``."""
    words = _alternatives(hint, option)
    return words[0] if len(words) == 1 else f"{', '.join(words[:-1])} or {words[-1]}"


def shown(value: Any, limit: int = 80) -> str:
    """A value as a reader wrote it (lists, not tuples), cut to one short line."""

    def plain(item: Any) -> Any:
        if isinstance(item, np.ndarray):
            item = item.tolist()
        if isinstance(item, list | tuple):
            return [plain(v) for v in item]
        return item

    text = " ".join(repr(plain(value)).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."
