"""Text cells of the CSV files a run folder holds, kept from running as spreadsheet formulas.

A spreadsheet (Excel, LibreOffice Calc, Google Sheets) that opens a CSV file reads a cell that
begins with ``=``, ``+``, ``-``, ``@``, tab, carriage return or line feed as a formula, so a
label such as ``=cmd|' /C calc'!A0`` or ``@HYPERLINK("...")`` (or an estimator's message)
would run when ``summary.csv`` is opened. Following the OWASP "CSV Injection" page:

- a text cell whose first character is one of :data:`FORMULA_TRIGGERS` gets a single quote
  ``'`` in front (:func:`neutralised_cell`); a ``-`` that begins a number (``-3.5``,
  ``-1e-05``, ``-inf``) is left alone, and numeric columns are never changed;
- every text cell is wrapped in double quotes, a double quote inside it doubled
  (:data:`QUOTING`, RFC 4180), so a field separator inside a label (``,`` or the ``;`` of
  spreadsheets in many locales) cannot start a new cell that begins with a trigger.

The change is invertible: a cell that begins with quotes followed by a trigger gets one more
quote, so :func:`original_text` (one quote removed from such a cell) gives back the exact text.
The files are views; the run's source of truth is ``results.sqlite`` (and ``experiment.json``
for the labels), from which ``emitterbench report`` writes them again, and nothing in
emitterbench reads them back.
"""

from __future__ import annotations

import csv
import os
import re

import numpy as np
import pandas as pd

FORMULA_TRIGGERS = ("=", "+", "-", "@", "\t", "\r", "\n")
"""First characters that make a spreadsheet read a cell as a formula (OWASP)."""

QUOTING = csv.QUOTE_NONNUMERIC
"""Every text cell in double quotes; numbers bare."""

_NUMBER = r"-(?:(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?|inf)$"
_GUARDED = re.compile(r"'*(?:[=+@\t\r\n]|-(?!" + _NUMBER[1:] + r"))")
"""A cell, after any leading quotes, begins with a trigger (a ``-`` not starting a number)."""


def neutralised_cell(text: str) -> str:
    """``text`` with a leading ``'`` if it begins (after any quotes) with a formula trigger."""
    return "'" + text if _GUARDED.match(text) else text


def original_text(cell: str) -> str:
    """The text a cell of :func:`neutralised_cell` was made from (its inverse)."""
    return cell[1:] if cell.startswith("'") and _GUARDED.match(cell[1:]) else cell


def neutralised_frame(frame: pd.DataFrame) -> pd.DataFrame:
    """``frame`` with every text cell and column name through :func:`neutralised_cell`.

    Numeric, boolean and missing cells are unchanged; ``frame`` itself is returned when no
    cell needs a quote (the common case costs one vectorised match per text column).
    """
    changed: dict[str, pd.Series] = {}
    for name in frame.columns:
        column = frame[name]
        if pd.api.types.is_numeric_dtype(column) or pd.api.types.is_bool_dtype(column):
            continue
        if isinstance(column.dtype, pd.StringDtype):  # text or missing: match directly
            guarded = column.str.match(_GUARDED.pattern).fillna(False).astype(bool)
        else:
            texts = column.map(lambda value: isinstance(value, str)).astype(bool)
            guarded = texts & column.where(texts, "").str.match(_GUARDED.pattern).astype(bool)
        if guarded.any():
            values = column.astype(object)
            changed[str(name)] = values.mask(guarded, "'" + values.where(guarded, ""))
    renamed = {name: neutralised_cell(name) for name in frame.columns if isinstance(name, str)}
    if not changed and all(name == new for name, new in renamed.items()):
        return frame
    return frame.assign(**changed).rename(columns=renamed)


_TRIGGERED = frozenset("'" + "".join(FORMULA_TRIGGERS))
"""First characters after which :func:`neutralised_cell` has something to check."""


def _quoted_cell(text: str) -> str:
    """A text cell as written: neutralised, in double quotes, inner quotes doubled."""
    if text[:1] in _TRIGGERED:
        text = neutralised_cell(text)
    return '"' + (text.replace('"', '""') if '"' in text else text) + '"'


def _column_cells(column: pd.Series) -> list[str] | None:
    """The cells of one column as :func:`csv_text` writes them, or None for a type it leaves
    to pandas (only float64, numpy integers and booleans, and text with missing values).

    Each distinct value is formatted once (a point's columns repeat within it): floats by
    ``repr`` (distinct bit patterns, so ``-0.0`` stays), integers and booleans by ``str``,
    text by :func:`_quoted_cell`; a missing value is ``""``, pandas' empty ``na_rep`` quoted.
    """
    dtype = column.dtype
    if isinstance(dtype, pd.StringDtype) or dtype == np.dtype(object):
        codes, distinct = pd.factorize(column.to_numpy(dtype=object), use_na_sentinel=True)
        texts = distinct.tolist()
        if not all(isinstance(text, str) for text in texts):
            return None  # numbers among the text: pandas writes them bare
        cells = [_quoted_cell(text) for text in texts]
    elif dtype == np.float64:
        values = column.to_numpy()
        codes, distinct = pd.factorize(values.view(np.int64), use_na_sentinel=False)
        floats = distinct.view(np.float64)
        cells = list(map(float.__repr__, floats.tolist()))
        for at in np.flatnonzero(np.isnan(floats)).tolist():
            cells[at] = '""'
    elif dtype == np.bool_ or (isinstance(dtype, np.dtype) and dtype.kind in "iu"):
        codes, distinct = pd.factorize(column.to_numpy(), use_na_sentinel=False)
        cells = list(map(str, distinct.tolist()))
    else:
        return None
    cells.append('""')  # code -1: missing
    return [cells[code] for code in codes.tolist()]


def csv_text(frame: pd.DataFrame, *, header: bool = True) -> str | None:
    """``frame`` as CSV text, byte for byte what pandas writes of :func:`neutralised_frame`
    with ``to_csv(index=False, quoting=QUOTING)``, about twice as fast (the trial rows of a
    run); None when a column holds a type that only pandas writes (numbers among text,
    float32, nullable integers, dates, a name that is not text)."""
    if frame.shape[1] == 0 or not all(isinstance(name, str) for name in frame.columns):
        return None
    columns = [_column_cells(frame.iloc[:, at]) for at in range(frame.shape[1])]
    if any(cells is None for cells in columns):
        return None
    lines = [",".join(map(_quoted_cell, frame.columns))] if header else []
    lines.extend(map(",".join, zip(*columns, strict=True)))  # type: ignore[arg-type]
    return os.linesep.join(lines) + os.linesep if lines else ""
