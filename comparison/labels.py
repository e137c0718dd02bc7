"""The labels a user gives (experiment name, estimator and planner labels): checked at load,
isolated where a page or a figure shows them.

A label names rows, table lines, legend entries and the subjects of the report's sentences,
so it is one short line of text:

- :func:`check_label` refuses, at load and with one line naming the key, a label longer than
  :data:`MAX_LABEL_CHARS` characters (a 10,000-character label would push the other entries
  out of a legend) or holding a control character (C0, DEL or C1: a tab or a line break
  would split a message, a table cell or a legend line).
- Unicode direction controls (:data:`BIDI_CONTROLS`) are allowed, since a label may be in a
  right-to-left script, but an unterminated one (a right-to-left override, U+202E) would
  reverse the text after it. The report's HTML puts every label inside ``<bdi>``
  (:func:`label_html`), which confines them to the label; figures (matplotlib draws text in
  logical order and has no glyph for them) and the page's title show each control as U+FFFD,
  the replacement character (:func:`plain_label`), so the reader sees that the label holds
  one. Two labels
  that differ only by direction controls would read the same, and are refused as duplicates
  (:func:`visible_label`).
"""

from __future__ import annotations

import html
import re

MAX_LABEL_CHARS = 64
"""Most characters of a label (estimator, planner) or an experiment name."""

BIDI_CONTROLS = (
    "\u061c"  # arabic letter mark
    "\u200e\u200f"  # left-to-right and right-to-left marks
    "\u202a\u202b\u202c\u202d\u202e"  # embeddings, pop, overrides
    "\u2066\u2067\u2068\u2069"  # isolates and pop
)
"""The Unicode direction (bidi) controls."""

_BIDI = re.compile(f"[{BIDI_CONTROLS}]")
_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f]")

LABEL_COLUMNS = ("experiment", "planner", "estimator")
"""The result columns that hold labels."""

PLAIN_MARK = "\ufffd"
"""What text without markup (a figure, the page's title) shows for a direction control."""


def check_label(value: object, path: str, *, fix: str = "give a shorter one") -> str:
    """``value`` if it is a label: a non-empty string of at most :data:`MAX_LABEL_CHARS`
    characters without control characters; else a ``ValueError`` naming ``path`` and ``fix``
    (what to do about a long label)."""
    if not isinstance(value, str) or not value:
        raise ValueError(f"{path}: expected a non-empty string, got {value!r}")
    if len(value) > MAX_LABEL_CHARS:
        raise ValueError(
            f"{path}: {len(value):,} characters ({value[:20]!r}...), more than the limit of "
            f"{MAX_LABEL_CHARS}; {fix}"
        )
    control = _CONTROL.search(value)
    if control:
        raise ValueError(
            f"{path}: {value!r} holds the control character U+{ord(control.group()):04X} at "
            f"position {control.start()}; a label is one line of printable text, remove it"
        )
    return value


def visible_label(label: str) -> str:
    """``label`` without its direction controls: what a reader sees of it."""
    return _BIDI.sub("", label)


def plain_label(label: str) -> str:
    """``label`` where no markup can isolate it (a figure, the page's title): each direction
    control shown as :data:`PLAIN_MARK`."""
    return _BIDI.sub(PLAIN_MARK, label)


def has_bidi_controls(label: str) -> bool:
    return _BIDI.search(label) is not None


def label_html(label: object) -> str:
    """``label`` escaped for HTML and isolated in ``<bdi>``: its direction controls, if any,
    act inside it only, and the text around it keeps its own direction."""
    return f"<bdi>{html.escape(str(label), quote=True)}</bdi>"
