"""The reports of a cross-check: ``validate.json``, ``validate.md``, ``validate.html`` and
the gap scatter ``validate_gaps.png``."""

from __future__ import annotations

import base64
import io
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from comparison.crosscheck.result import ValidationResult

_COLUMNS = (
    ("family", "family"),
    ("dimension", "d"),
    ("n", "n"),
    ("n_hard", "hard"),
    ("max_rel_objective_gap", "max rel. objective gap"),
    ("max_argmin_distance_m", "max argmin dist. (m)"),
    ("max_argmin_distance_rel", "(rel.)"),
    ("max_candidate_pair_distance_m", "max pair dist. (m)"),
    ("max_candidate_pair_distance_rel", "(rel.)"),
    ("statuses", "solver statuses"),
    ("tolerance_rungs", "tolerance rungs"),
    ("median_sdp_time_s", "median SDP time (ms)"),
    ("median_closed_form_time_s", "median closed-form time (ms)"),
    ("n_disagreements", "disagreements"),
)


_ESTIMATOR_COLUMNS = (
    ("family", "family"),
    ("dimension", "d"),
    ("n", "n"),
    ("n_hard", "hard"),
    ("n_sdp_failed", "SDP failed"),
    ("n_estimator_failed", "estimate failed"),
    ("max_estimator_rel_cost_gap", "max rel. cost gap of candidates"),
    ("max_estimator_distance_m", "max dist. to the minimisers (m)"),
    ("max_estimator_distance_rel", "(rel.)"),
    ("n_estimator_missing", "missing"),
    ("n_estimator_extra", "extra"),
    ("n_disagreements", "disagreements"),
)


def _estimator_caption(result: ValidationResult) -> str:
    return (
        f"The candidates of {result.estimator} ({result.estimator_args}) on its own constrained "
        "least squares, constrained_ls(data), for each instance's measurements: each candidate "
        "lifted onto the paraboloid and compared with the exact optimum of the same rows (MATH "
        f"§5). Tolerances: relative cost gap {result.rtol_objective:g}; distance to a "
        f"closed-form minimiser {result.rtol_argmin:g} of the length scale. Missing: "
        "closed-form minimisers not returned (both mirror images are due in the hard case, "
        "except in d = 3 one above the UAV's highest sample, which the mirror rule drops, "
        "MATH §7); "
        "extra: candidates that are not global minimisers. The table above compares the closed "
        "form and the SDP on the same rows."
    )


_INEQUALITY_COLUMNS = (
    ("family", "family"),
    ("n_multiplier_nonnegative", "λ* ≥ 0"),
    ("n_inequality_tight_when_nonnegative", "tight"),
    ("max_inequality_gap_when_nonnegative", "max gap"),
    ("n_multiplier_negative", "λ* < 0"),
    ("n_inequality_loose_when_negative", "not tight"),
    ("min_inequality_gap_when_negative", "min gap"),
)

_INEQUALITY_CAPTION = (
    "The inequality relaxation (r_z ≥ x² + y², in d = 3 r_w ≥ x² + y² + z², MATH §11) on the same "
    "instances: it is tight (value "
    "within the objective tolerance of the closed form's) when the Lagrange multiplier λ* ≥ 0, "
    "and strictly below the optimum when λ* < 0, by a gap that vanishes as λ* → 0⁻ (so a "
    "barely negative λ* can fall within the tolerance). Gaps are relative to the closed form's "
    "value."
)


def _cell(key: str, value: Any) -> str:
    if key in ("statuses", "tolerance_rungs"):
        return ", ".join(f"{k} {v}" for k, v in sorted(value.items()))
    if key.endswith("time_s"):
        return f"{value * 1e3:.2f}"
    if isinstance(value, float):
        return "–" if math.isnan(value) else f"{value:.2e}"
    return str(value)


def _table_rows(
    result: ValidationResult, columns: Sequence[tuple[str, str]] = _COLUMNS
) -> list[list[str]]:
    return [
        [_cell(key, getattr(summary, key)) for key, _ in columns]
        for summary in result.families.values()
    ]


def _title(result: ValidationResult) -> str:
    if result.estimator is None:
        return "Closed form vs SDP relaxation"
    return f"{result.estimator}: closed form vs SDP relaxation"


def _caption(result: ValidationResult) -> str:
    rows = (
        "the same stacked rows"
        if result.estimator is None
        else f"the rows of {result.estimator}.constrained_ls(data)"
    )
    return (
        f"Closed-form CLS (MATH §5) against its Shor SDP relaxation (MATH §11, cvxpy + "
        f"Clarabel) on {rows}; root seed {result.seed}. d: the emitter's coordinates, 2 "
        "(r = (x, y, x² + y²), the height known) or 3 (r = (x, y, z, x² + y² + z²), the height "
        "unknown; the lift 5×5). Tolerances: relative "
        f"objective gap {result.rtol_objective:g}; argmin distance (unique minimiser) and "
        f"mirror-pair distance (hard case) {result.rtol_argmin:g} of the length scale (RMS of "
        "the track spread and the ranges). Noise levels follow the SNR axis of MATH §2. "
        "Tolerance rung 1: Clarabel at gap 1e-10, feasibility 1e-9; rung 2 (used when rung 1 "
        "ends optimal_inaccurate): Clarabel's defaults, 1e-8."
    )


def write_reports(result: ValidationResult, out_dir: Path) -> dict[str, Path]:
    """Write ``validate.json``, ``validate.md``, ``validate_gaps.png`` and ``validate.html``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    files = {
        "json": out_dir / "validate.json",
        "md": out_dir / "validate.md",
        "png": out_dir / "validate_gaps.png",
        "html": out_dir / "validate.html",
    }
    files["json"].write_text(json.dumps(result.to_dict(), indent=2) + "\n", encoding="utf-8")
    png = gap_scatter_png(result)
    files["png"].write_bytes(png)
    files["md"].write_text(markdown_report(result), encoding="utf-8")
    files["html"].write_text(html_report(result, png), encoding="utf-8")
    return files


def _disagreement_lines(result: ValidationResult, limit: int = 200) -> list[str]:
    lines = []
    for r in result.disagreements[:limit]:
        lines.append(
            f"{r.family} seed {r.seed}: {'; '.join(r.reasons)} (replay: {result.replay_command(r)})"
        )
    if len(result.disagreements) > limit:
        lines.append(f"... and {len(result.disagreements) - limit} more (see validate.json)")
    return lines


def _skipped_lines(result: ValidationResult) -> list[str]:
    """One line per reason a family was not run (families of the same reason together)."""
    by_reason: dict[str, list[str]] = {}
    for family, why in result.skipped.items():
        by_reason.setdefault(why, []).append(family)
    return [f"{', '.join(families)}: {why}." for why, families in by_reason.items()]


def markdown_report(result: ValidationResult) -> str:
    """A short Markdown summary: verdict, the per-family table, every disagreement."""
    headers = [title for _, title in _COLUMNS]
    lines = [
        f"# {_title(result)}",
        "",
        f"**{'PASS' if result.ok else 'FAIL'}**: {len(result.results)} instances, "
        f"{len(result.disagreements)} disagreements.",
        "",
        _caption(result),
        "",
        "| " + " | ".join(headers) + " |",
        "|" + "|".join("---" for _ in headers) + "|",
    ]
    lines += ["| " + " | ".join(row) + " |" for row in _table_rows(result)]
    lines += [f"\nNot run: {line}" for line in _skipped_lines(result)]
    if result.estimator is not None:
        estimator_headers = [title for _, title in _ESTIMATOR_COLUMNS]
        lines += [
            "",
            "## The estimator's candidates",
            "",
            _estimator_caption(result),
            "",
            "| " + " | ".join(estimator_headers) + " |",
            "|" + "|".join("---" for _ in estimator_headers) + "|",
        ]
        lines += ["| " + " | ".join(row) + " |" for row in _table_rows(result, _ESTIMATOR_COLUMNS)]
    inequality_headers = [title for _, title in _INEQUALITY_COLUMNS]
    lines += [
        "",
        "## The inequality relaxation",
        "",
        _INEQUALITY_CAPTION,
        "",
        "| " + " | ".join(inequality_headers) + " |",
        "|" + "|".join("---" for _ in inequality_headers) + "|",
    ]
    lines += ["| " + " | ".join(row) + " |" for row in _table_rows(result, _INEQUALITY_COLUMNS)]
    lines += ["", "## Disagreements", ""]
    found = _disagreement_lines(result)
    lines += [f"- {line}" for line in found] if found else ["None."]
    lines += ["", "Objective gaps: `validate_gaps.png`.", ""]
    return "\n".join(lines)


def html_report(result: ValidationResult, png: bytes) -> str:
    """The same content as HTML, the gap scatter embedded as a PNG data URI."""
    from html import escape

    head = "".join(f"<th>{escape(title)}</th>" for _, title in _COLUMNS)
    body = "".join(
        "<tr>" + "".join(f"<td>{escape(cell)}</td>" for cell in row) + "</tr>"
        for row in _table_rows(result)
    )
    inequality_head = "".join(f"<th>{escape(title)}</th>" for _, title in _INEQUALITY_COLUMNS)
    inequality_body = "".join(
        "<tr>" + "".join(f"<td>{escape(cell)}</td>" for cell in row) + "</tr>"
        for row in _table_rows(result, _INEQUALITY_COLUMNS)
    )
    estimator_block = ""
    if result.estimator is not None:
        estimator_head = "".join(f"<th>{escape(title)}</th>" for _, title in _ESTIMATOR_COLUMNS)
        estimator_body = "".join(
            "<tr>" + "".join(f"<td>{escape(cell)}</td>" for cell in row) + "</tr>"
            for row in _table_rows(result, _ESTIMATOR_COLUMNS)
        )
        estimator_block = (
            "<h2>The estimator's candidates</h2>\n"
            f"<p>{escape(_estimator_caption(result))}</p>\n"
            f"<table><tr>{estimator_head}</tr>{estimator_body}</table>\n"
        )
    found = _disagreement_lines(result)
    items = "".join(f"<li>{escape(line)}</li>" for line in found) or "<li>None.</li>"
    image = base64.b64encode(png).decode("ascii")
    verdict = "PASS" if result.ok else "FAIL"
    return (
        "<!DOCTYPE html>\n<html><head><meta charset='utf-8'>"
        f"<title>{escape(_title(result))}</title>"
        "<style>body{font-family:sans-serif;max-width:70em;margin:2em auto}"
        "table{border-collapse:collapse}td,th{border:1px solid #999;padding:.2em .5em}"
        "</style></head><body>\n"
        f"<h1>{escape(_title(result))}: {verdict}</h1>\n"
        f"<p>{len(result.results)} instances, {len(result.disagreements)} disagreements.</p>\n"
        f"<p>{escape(_caption(result))}</p>\n"
        f"<table><tr>{head}</tr>{body}</table>\n"
        + "".join(f"<p>Not run: {escape(line)}</p>\n" for line in _skipped_lines(result))
        + f"{estimator_block}"
        "<h2>The inequality relaxation</h2>\n"
        f"<p>{escape(_INEQUALITY_CAPTION)}</p>\n"
        f"<table><tr>{inequality_head}</tr>{inequality_body}</table>\n"
        f"<h2>Disagreements</h2><ul>{items}</ul>\n"
        f"<h2>Objective gaps</h2><img alt='relative objective gap per instance' "
        f"src='data:image/png;base64,{image}'>\n"
        "</body></html>\n"
    )


def gap_scatter_png(result: ValidationResult) -> bytes:
    """Scatter of the relative objective gaps per instance, by family, hard vs unique (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    floor = 1e-17
    figure, axes = plt.subplots(figsize=(9.5, 4.5), dpi=100)
    offset = 0
    for index, family in enumerate(result.families):
        rows = [r for r in result.results if r.family == family]
        x = offset + np.arange(len(rows))
        gaps = np.array([r.rel_objective_gap for r in rows], dtype=float)
        gaps = np.where(np.isfinite(gaps), np.maximum(gaps, floor), np.nan)
        hard = np.array([r.hard_case for r in rows], dtype=bool)
        for mask, marker, kind in ((hard, "o", "hard case"), (~hard, "x", "unique")):
            if mask.any():
                axes.scatter(
                    x[mask],
                    gaps[mask],
                    s=8,
                    marker=marker,
                    color=f"C{index}",
                    label=f"{family} ({kind})",
                )
        offset += len(rows)
    axes.axhline(result.rtol_objective, color="k", linestyle="--", linewidth=1, label="tolerance")
    axes.set_yscale("log")
    axes.set_xlabel("instance (grouped by family)")
    axes.set_ylabel(f"|v_sdp − v_cf| / v_cf (floored at {floor:g})")
    axes.set_title("SDP relaxation vs closed form: relative objective gap")
    axes.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    figure.tight_layout()
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png")
    plt.close(figure)
    return buffer.getvalue()
