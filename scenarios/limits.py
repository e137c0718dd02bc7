"""Limits on what a file may hold and a run may ask for, and reading text and JSON within them.

Every limit is checked before the work it would cost, and its error names the field, the limit
and how to raise it. The resource limits have a default here and an environment variable that
raises it for a researcher who needs more (``EMITTERBENCH_MAX_SAMPLES=200000``):

=============================  ==========  ================================  =================
limit                          default     environment variable              used by
=============================  ==========  ================================  =================
measurement file size          32 MiB      ``EMITTERBENCH_MAX_FILE_MB``      measurement files
samples in a measurement set   100 000     ``EMITTERBENCH_MAX_SAMPLES``      files, experiments
frames in a measurement set    10 000      ``EMITTERBENCH_MAX_FRAMES``       files, experiments
=============================  ==========  ================================  =================

Two parsing limits are fixed: arrays and objects nest at most :data:`MAX_NESTING_DEPTH` levels
(no format here nests more than 5), and an integer has at most 4300 digits, Python's
int-to-string limit (``sys.get_int_max_str_digits``): :func:`load_json` reads a longer one as
a :class:`LongInteger`, which no field accepts. This module imports only the standard
library.

:func:`write_text_atomically` writes a file whole or not at all (a temporary file beside it,
then ``os.replace``).
"""

from __future__ import annotations

import json
import math
import os
import re
import tempfile
from collections.abc import Iterable
from pathlib import Path
from typing import Any

MAX_FILE_MB = 32
"""Largest measurement file read, MiB (``EMITTERBENCH_MAX_FILE_MB``): about 140 000 samples."""
MAX_SAMPLES = 100_000
"""Most samples in one measurement set, read or simulated (``EMITTERBENCH_MAX_SAMPLES``)."""
MAX_FRAMES = 10_000
"""Most frames in one measurement set (``EMITTERBENCH_MAX_FRAMES``): ekf and gtsam-smoother
take about 2 ms a frame, so 20 s at the limit."""
MAX_NESTING_DEPTH = 32
"""Deepest nesting of arrays and objects read from JSON or TOML."""

FILE_MB = (MAX_FILE_MB, "EMITTERBENCH_MAX_FILE_MB")
SAMPLES = (MAX_SAMPLES, "EMITTERBENCH_MAX_SAMPLES")
FRAMES = (MAX_FRAMES, "EMITTERBENCH_MAX_FRAMES")
"""Each limit as ``(default, environment variable)``, for :func:`check_limit`."""

TOO_DEEP = (
    f"arrays and objects nest more than {MAX_NESTING_DEPTH} levels deep; no field nests that "
    "deep, fix the structure"
)
_PLAIN_KEY = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


# --------------------------------------------------------------------------------------------
# resource limits
# --------------------------------------------------------------------------------------------


def configured_limit(limit: tuple[int, str]) -> int:
    """The default of ``limit = (default, variable)``, or the environment variable's value."""
    default, variable = limit
    text = os.environ.get(variable, "").strip()
    if not text:
        return default
    if not text.isdigit() or len(text) > 18 or int(text) < 1:
        raise ValueError(
            f"{variable}: expected a whole number >= 1, got {clip(text)!r}; fix or unset "
            "this environment variable"
        )
    return int(text)


def check_limit(count: int, path: str, what: str, limit: tuple[int, str], fix: str) -> None:
    """Raise ``ValueError`` naming ``path`` when ``count`` exceeds ``limit``.

    ``what`` names the counted things (``"trials per point"``), ``fix`` how to need fewer.
    """
    allowed = configured_limit(limit)
    if count > allowed:
        raise ValueError(
            f"{path}: {count_text(count)} {what}, more than the limit of {allowed:,}; {fix}, "
            f"or raise the limit with the environment variable {limit[1]}=N"
        )


def count_text(count: int) -> str:
    """``1,234`` or, for a huge whole number, ``about 10^4000`` (never 4000 digits)."""
    if abs(count) < 10**15:
        return f"{count:,}"
    return f"about {'-' * (count < 0)}10^{int(abs(count).bit_length() * math.log10(2))}"


# --------------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------------


def read_text(path: Path, *, field: str | None = None, limit_mb: tuple[int, str] = FILE_MB) -> str:
    """The UTF-8 text of ``path`` (a leading byte order mark dropped), within ``limit_mb`` MiB.

    The size is checked before reading and the read stops at the limit, whatever the file
    system says (a FIFO, a device). Errors start with ``field`` and the path, or the path
    alone when ``field`` is None; ``limit_mb`` is ``(MiB, variable)``, the variable ``""``
    when the limit is fixed.
    """
    where = str(path) if field is None else f"{field}: {path}"
    allowed = configured_limit(limit_mb) if limit_mb[1] else limit_mb[0]
    too_large = f"{where}: larger than the limit of {allowed} MiB; use a smaller file" + (
        f", or raise the limit with the environment variable {limit_mb[1]}=N" if limit_mb[1] else ""
    )
    try:
        if path.stat().st_size > allowed * 2**20:
            raise ValueError(too_large)
        with path.open("rb") as handle:
            content = handle.read(allowed * 2**20 + 1)
    except FileNotFoundError:
        raise ValueError(f"{where}: no such file; check the path") from None
    except OSError as error:
        raise ValueError(f"{where}: cannot read ({error.strerror or error})") from None
    if len(content) > allowed * 2**20:
        raise ValueError(too_large)
    try:
        return content.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        raise ValueError(
            f"{where}: not UTF-8 text ({error.reason} at byte {error.start}); save it as UTF-8"
        ) from None


def load_json(text: str, *, source: str) -> Any:
    """JSON text as Python values, within the parsing limits; a leading BOM is ignored.

    Bad syntax and nesting deeper than :data:`MAX_NESTING_DEPTH` are errors starting with
    ``source``, a key twice in one object an error naming the key; an integer of more than
    4300 digits is read as a :class:`LongInteger`.
    """
    try:
        obj = json.loads(
            text.removeprefix("\ufeff"),
            object_pairs_hook=_without_duplicate_keys,
            parse_int=_integer,
        )
    except json.JSONDecodeError as error:
        raise ValueError(
            f"{source}: invalid JSON at line {error.lineno}, column {error.colno} "
            f"({error.msg}); fix the syntax"
        ) from None
    except RecursionError:
        raise ValueError(f"{source}: {TOO_DEEP}") from None
    check_nesting(obj)
    return obj


def check_nesting(obj: Any, *, limit: int = MAX_NESTING_DEPTH) -> None:
    """Raise ``ValueError`` naming the first list or dict nested deeper than ``limit``.

    Iterative, so it never recurses itself; the message names the first four levels of the
    path (``samples[0].toa_s[0]``).
    """
    stack = [(obj, (), 1)] if isinstance(obj, dict | list) else []
    while stack:
        value, path, depth = stack.pop()
        if depth > limit:
            raise ValueError(f"{key_path(path[:4]) or 'root'}: {TOO_DEEP}")
        items = value.items() if isinstance(value, dict) else enumerate(value)
        stack.extend(
            (item, (*path, key), depth + 1) for key, item in items if isinstance(item, dict | list)
        )


class LongInteger:
    """An integer of more than 4300 digits in a JSON file, kept as its number of digits:
    Python refuses to convert it (``sys.get_int_max_str_digits``), and no field takes it."""

    __slots__ = ("digits",)

    def __init__(self, digits: int) -> None:
        self.digits = digits

    def __repr__(self) -> str:
        return f"an integer of {self.digits} digits"


def _integer(text: str) -> int | LongInteger:
    try:
        return int(text)
    except ValueError:  # more digits than sys.get_int_max_str_digits()
        return LongInteger(len(text.lstrip("-")))


def _without_duplicate_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    obj: dict[str, Any] = {}
    for key, value in pairs:
        if key in obj:
            raise ValueError(f"{key_path([key])}: appears twice in one JSON object; keep only one")
        obj[key] = value
    return obj


# --------------------------------------------------------------------------------------------
# naming what is wrong
# --------------------------------------------------------------------------------------------


def key_path(parts: Iterable[Any]) -> str:
    """``samples[2].toa_s`` from ``("samples", 2, "toa_s")``; odd keys quoted: ``noise["a b"]``.

    A message's first word is its field, so a key with spaces or punctuation is written as a
    JSON string, and a long one shortened.
    """
    text = ""
    for part in parts:
        if isinstance(part, int):
            text += f"[{part}]"
        elif _PLAIN_KEY.fullmatch(part):
            text += f".{part}" if text else part
        else:
            text += f"[{json.dumps(clip(part))}]"
    return text


def child_path(path: str, key: str) -> str:
    """``path.key`` (``noise.toa_s``), or ``key`` alone at the top; odd keys as in :func:`key_path`."""
    if path and _PLAIN_KEY.fullmatch(key):
        return f"{path}.{key}"
    return path + key_path([key])


def clip(text: str, length: int = 40) -> str:
    """``text``, or its start and length when longer than ``length`` characters."""
    return text if len(text) <= length else f"{text[:length]}... ({len(text):,} characters)"


def write_text_atomically(text: str, path: Path) -> None:
    """Write to a temporary file beside ``path``, then ``os.replace`` it over ``path``."""
    folder = path.parent
    if not folder.is_dir():
        raise ValueError(f"output: folder {folder} does not exist; create it first")
    mode = path.stat().st_mode & 0o777 if path.exists() else 0o644
    try:
        descriptor, temporary = tempfile.mkstemp(dir=folder, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as error:
        raise ValueError(f"output: cannot write in {folder} ({error.strerror or error})") from None
    try:
        with os.fdopen(descriptor, "w", encoding="utf-8", newline="\n") as handle:
            handle.write(text)
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(temporary, mode)
        os.replace(temporary, path)
    except BaseException as error:
        Path(temporary).unlink(missing_ok=True)
        if isinstance(error, OSError):
            raise ValueError(f"output: cannot write {path} ({error.strerror or error})") from None
        raise
