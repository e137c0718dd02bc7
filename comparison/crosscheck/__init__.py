"""Cross-check the closed-form CLS against its SDP relaxation on seeded instances (MATH §5, §11).

The SDP relaxation (:func:`estimators.sdp.sdp_cls.solve_sdp_relaxation`) is an independent witness
for the closed form (:func:`estimators.closed_form.gtrs.solve_gtrs`): on the same stacked rows its
optimal value must equal the closed form's on every instance, and its argmin must equal the closed
form's minimiser when that is unique; in the hard case (MATH §5) the mirror pair recovered from
the rank-two lift must equal the closed form's pair. Where they part, the report says why, with
the instance's own seed so :func:`replay` can re-run it verbosely.

Families of instances (each drawn from its own ``SeedSequence``):

``straight``
    One straight frame: random heading, speed, K, sample interval, height, carrier, emitter and
    noise levels; weighted rows (MATH §6, stage 1). Mostly the hard case.
``turn``
    Two frames at different headings, unweighted per-sample rows (SI units).
``turn-weighted``
    The same geometries with weighted rows.
``paper``
    The paper's geometry (MATH §14) with the ``paper-1m`` or ``paper-10m`` constants at a
    random SNR (MATH §2), weighted rows.
``climb-height`` (3-D)
    The emitter's height unknown, ``r = (x, y, z, x² + y² + z²)`` (MATH §5 in three
    coordinates, the lift 5×5): three legs at random headings, each at its own climb rate, the
    emitter at a random height below the UAV; weighted rows. No plane holds the flight: one
    minimiser.
``level-height`` (3-D)
    The same with a level flight: its rows annihilate ``(0, 0, 1, 2h)`` and the emitter's
    reflection through the flight plane costs the same (MATH §7): the hard case, both
    minimisers due (unless the noise leaves one, in the plane).

Length scale: every distance is also given relative to the problem's length scale, the
:class:`~estimators.closed_form.cls_rows.LocalFrame` scale (RMS of the track spread and the ranges).

Another closed form (``run_validation(estimator=...)``, ``emitterbench validate --estimator
NAME``). An estimator that exposes the constrained least squares it minimises,
``constrained_ls(data) -> ConstrainedLS`` (:mod:`estimators.closed_form.constrained_ls`), is run on
every instance's measurements (the same geometry and noise draws). Its own rows replace the
family's: the closed form and the SDP are compared on them as above, and every candidate the
estimator returns is lifted onto the paraboloid and must attain the closed-form optimum (relative
cost gap ``<= rtol_objective``, within ``rtol_argmin`` of the length scale of a closed-form
minimiser), and every closed-form minimiser must be among its candidates (both mirror images in
the hard case, MATH §5), except, with the height unknown, one above the UAV's highest sample,
which the mirror rule drops (MATH §7). A disagreement is replayed with ``--replay SEED --families F
--estimator NAME``.

The command is ``emitterbench validate``. Modules: :mod:`~comparison.crosscheck.instances`
(the seeded families), :mod:`~comparison.crosscheck.compare` (one instance: closed form, SDP,
an estimator's candidates), :mod:`~comparison.crosscheck.run` (a run over families and its
result), :mod:`~comparison.crosscheck.reports` (json, md, html, png) and
:mod:`~comparison.crosscheck.replay` (one instance verbosely).
"""

from __future__ import annotations

from comparison.crosscheck.compare import (
    NOT_RUN,
    CandidateCheck,
    EstimatorRun,
    InstanceResult,
    check_candidates,
    check_protocol,
    compare_solutions,
    estimator_label,
    point_set_distance,
    relative_objective_gap,
    validate_estimator_instance,
    validate_instance,
)
from comparison.crosscheck.instances import (
    FAMILIES,
    FAMILY_DIMENSION,
    FloatArray,
    ValidationInstance,
    instance_seeds,
    make_instance,
)
from comparison.crosscheck.replay import replay, replay_with_verdict
from comparison.crosscheck.reports import (
    gap_scatter_png,
    html_report,
    markdown_report,
    write_reports,
)
from comparison.crosscheck.result import FamilySummary, ValidationResult, replay_command
from comparison.crosscheck.run import (
    MULTIPLIER_ZERO_RTOL,
    Progress,
    estimator_cli_args,
    run_validation,
    summarise_family,
)

__all__ = [
    "FAMILIES",
    "FAMILY_DIMENSION",
    "MULTIPLIER_ZERO_RTOL",
    "NOT_RUN",
    "CandidateCheck",
    "EstimatorRun",
    "FamilySummary",
    "FloatArray",
    "InstanceResult",
    "Progress",
    "ValidationInstance",
    "ValidationResult",
    "check_candidates",
    "check_protocol",
    "compare_solutions",
    "estimator_cli_args",
    "estimator_label",
    "gap_scatter_png",
    "html_report",
    "instance_seeds",
    "make_instance",
    "markdown_report",
    "point_set_distance",
    "relative_objective_gap",
    "replay",
    "replay_command",
    "replay_with_verdict",
    "run_validation",
    "summarise_family",
    "validate_estimator_instance",
    "validate_instance",
    "write_reports",
]
