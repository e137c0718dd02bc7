"""What the commands of :mod:`comparison.cli` print for a person: the version, the summaries of
``estimate``, ``crlb``, ``fly`` and ``validate`` (``--json`` prints the data themselves,
:func:`comparison.cli_support.print_json`)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from scenarios.types import MeasurementSet


def version_text() -> str:
    """``emitterbench 0.1.0``: the installed distribution's version (importlib.metadata)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return f"emitterbench {version('emitterbench')}"
    except PackageNotFoundError:
        return "emitterbench (version unknown: not installed; pip install -e .)"


def console() -> Any:
    """A rich console on stdout that neither colours numbers nor wraps long lines."""
    from rich.console import Console

    return Console(highlight=False, soft_wrap=True)


def point_text(point: Any) -> str:
    """``(35.0000, -15.0000)``; ``nan`` for a coordinate that is not finite."""
    return "(" + ", ".join("nan" if not math.isfinite(v) else f"{v:.4f}" for v in point) + ")"


def ambiguity_text(candidates_m: Any, seen: MeasurementSet) -> str:
    """What ``ambiguous: yes`` means for these candidates and the samples the estimator saw.

    Two candidates or more: the data cannot tell them apart. One, on the straight track of
    ``seen``: it is its own mirror image, so the side of the track stays unknown (MATH §7).
    """
    import numpy as np

    from scenarios.geometry import cross_track_m, straight_track_line

    points = np.asarray(candidates_m, dtype=float)
    points = points.reshape(-1, points.shape[-1] if points.ndim > 1 else 2)  # (x, y[, z])
    if len(points) >= 2:
        return f"yes: the data cannot tell these {len(points)} candidates apart (MATH §7)"
    line = straight_track_line(seen.position_m, seen.velocity_mps)
    side = "yes: the side of the track cannot be told from these data"
    if line is not None and len(points) == 1:
        origin, direction = line
        reach_m = max(float(np.linalg.norm(points[0, :2] - origin)), 1.0)
        if abs(float(cross_track_m(points[0, :2], origin, direction))) <= 1e-6 * reach_m:
            return f"{side}; the single candidate lies on the track (MATH §7)"
    return f"{side}, says the estimator (MATH §7)"


def print_estimate(
    result: dict[str, Any], file: Path, data: MeasurementSet, ambiguity: str
) -> None:
    """The summary of ``estimate``: the estimate's fields (:func:`comparison.scoring.
    estimate_to_dict`), one a line, with ``ambiguity`` (:func:`ambiguity_text`) as its flag."""
    from rich.table import Table

    def point(value: list[float | None] | None) -> str:
        return "-" if value is None else point_text([math.nan if v is None else v for v in value])

    table = Table.grid(padding=(0, 2))
    table.add_column(style="bold")
    table.add_column()
    table.add_row("estimator", result["estimator"])
    table.add_row(
        "data",
        f"{file}: {data.n_samples} samples, {len(data.frames)} frame(s), "
        f"{', '.join(sorted(data.modalities))}",
    )
    table.add_row("success", "yes" if result["success"] else "NO")
    table.add_row("position_m", point(result["position_m"]))
    table.add_row("candidates_m", "  ".join(point(c) for c in result["candidates_m"]) or "-")
    if result["ambiguous"]:
        table.add_row("ambiguous", ambiguity)
    if result["covariance_m2"] is not None:
        table.add_row("covariance_m2", str(result["covariance_m2"]))
    if "error_m" in result:
        table.add_row(
            "error_m",
            f"{number_text(result['error_m'])} (side resolved: "
            f"{number_text(result['error_side_resolved_m'])})",
        )
    if result["message"]:
        table.add_row("message", result["message"])
    for key, value in result["diagnostics"].items():
        table.add_row(f"  {key}", str(value))
    console().print(table)


def number_text(value: float | None) -> str:
    """Four significant digits, or ``-`` for no value."""
    return "-" if value is None else f"{value:.4g}"


def print_crlb_table(table: dict[str, Any], data: MeasurementSet) -> None:
    """The CRLB table of ``crlb`` (:func:`comparison.crlb.crlb_table`) as a rich table."""
    from rich.table import Table

    unknowns = table["unknowns"]
    title = f"CRLB at {point_text(table['at_m'])} m, {data.n_samples} samples"
    three_d = "vertical_rmse_bound_m" in table  # its 3×3 matrices are in --json
    if unknowns:
        from scenarios.nuisance import math_sections

        title += f", {' and '.join(unknowns)} unknown ({math_sections(unknowns)})"
    view = Table(title=title, caption="the 3×3 CRLB matrices: --json" if three_d else None)
    headings = ["modalities", "√trace CRLB (m)"]
    headings += ["horizontal (m)", "vertical (m)"] if three_d else ["CRLB (m²)"]
    if unknowns:
        headings += ["known: √trace CRLB (m)", "price"]
    for heading in (*headings, "note"):
        view.add_column(heading)
    for name in table["rmse_bound_m"]:
        bound, matrix = table["rmse_bound_m"][name], table["crlb_m2"][name]
        cells = [name, number_text(bound)]
        if three_d:
            cells += [
                number_text(table["horizontal_rmse_bound_m"].get(name)),
                number_text(table["vertical_rmse_bound_m"].get(name)),
            ]
        else:
            cells.append(
                "-"
                if matrix is None
                else "; ".join(" ".join(f"{v:.3g}" for v in r) for r in matrix)
            )
        if unknowns:
            price = table["price"].get(name)
            cells += [
                number_text(table["known_rmse_bound_m"].get(name)),
                "-" if price is None else f"{price:.3g}×",
            ]
        view.add_row(*cells, table["notes"].get(name, ""))
    console().print(view)


def print_plan(result: dict[str, Any], file: Path) -> None:
    """The summary of ``fly``: the next velocity, the flight so far and the steering estimate."""
    from rich.table import Table

    table = Table.grid(padding=(0, 2))
    table.add_column(style="bold")
    table.add_column()
    table.add_row("planner", result["planner"])
    flight = result["flight"]
    table.add_row(
        "flight",
        f"{file}: {flight['frames']} frame(s) of {flight['samples_per_frame']} samples, "
        f"Δ = {flight['sample_interval_s']:g} s",
    )
    table.add_row("velocity_mps", point_text(result["velocity_mps"]))
    table.add_row(
        "speed, heading",
        f"{result['speed_mps']:.4g} m/s, {result['heading_deg']:.4g}° (from east, counter-clockwise)",
    )
    table.add_row("next frame from", point_text(flight["next_frame_start_m"]))
    table.add_row("message", result["message"] or "-")
    estimate = result["estimate"]
    others = [c for c in estimate["candidates_m"] if c != estimate["position_m"]]
    table.add_row(
        "estimate",
        f"{estimate['estimator']}: {point_text(estimate['position_m'])}"
        + (f"; mirror {'  '.join(point_text(c) for c in others)}" if others else "")
        + (" (ambiguous, MATH §7: the planner uses the first)" if estimate["ambiguous"] else ""),
    )
    console().print(table)


def validation_lines(result: Any) -> list[str]:
    """The summary of ``validate``: a line per family (and the estimator judged, if any)."""
    lines = []
    if result.estimator is not None:
        lines.append(
            f"estimator {result.estimator}: its own rows (constrained_ls) on each instance"
        )
    for name, summary in result.families.items():
        if result.estimator is None:
            lines.append(
                f"{name:<14} n={summary.n:<5} hard={summary.n_hard:<5} "
                f"max rel. gap {summary.max_rel_objective_gap:.1e}  "
                f"max argmin dist. {summary.max_argmin_distance_rel:.1e}  "
                f"max pair dist. {summary.max_candidate_pair_distance_rel:.1e} "
                "(of the length scale)  "
                f"disagreements {summary.n_disagreements}"
            )
        else:
            lines.append(
                f"{name:<14} n={summary.n:<5} hard={summary.n_hard:<5} "
                f"max rel. cost gap {summary.max_estimator_rel_cost_gap:.1e}  "
                f"max dist. {summary.max_estimator_distance_m:.1e} m "
                f"({summary.max_estimator_distance_rel:.1e} of the length scale)  "
                f"missing {summary.n_estimator_missing}  extra {summary.n_estimator_extra}  "
                f"SDP: max rel. gap {summary.max_rel_objective_gap:.1e}, "
                f"failed {summary.n_sdp_failed}  "
                f"disagreements {summary.n_disagreements}"
            )
    return lines
