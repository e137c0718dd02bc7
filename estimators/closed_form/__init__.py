"""The closed-form constrained least squares (docs/math.md §3-§6) and its pseudo-range forms
for non-cooperative emitters (§15).

Estimators: ``cls`` (:class:`Cls`), ``cls-paper`` (:class:`ClsPaper`), ``cls-as-printed``
(:class:`ClsAsPrinted`). The rows (§3-§4) and their weighting (§6) are built for every trial
at once in :mod:`~estimators.closed_form.cls_batch`, and the GTRS (§5) solved exactly for every
trial at once in :mod:`~estimators.closed_form.gtrs_batch`; :func:`solve_gtrs` is its batch of
one for a given system, :func:`cls_rows` one trial's rows.
With an unknown emission time (§15) the pseudo-range form,
:mod:`~estimators.closed_form.pseudorange_cls`, and its indefinite GTRS,
:mod:`~estimators.closed_form.gtrs_indefinite`, are likewise vectorised over trials, and so is
the second stage of its two-stage form (``offset_method="two-stage"``),
:mod:`~estimators.closed_form.pseudorange_two_stage`.
The reference path is the batch: ``Cls.estimate`` is the batch of one trial.

With the emitter's height among the data's unknowns, ``cls`` solves the same GTRS in one more
dimension, ``r = (x, y, z, ‖s‖²)`` (MATH §3-§5): the rows carry the height's column
(:class:`~estimators.closed_form.gtrs_batch.RowBlock` ``ah``) and the solver is the same code.
"""

from estimators.closed_form.cls import Cls, ClsAsPrinted, ClsPaper, cls_rows
from estimators.closed_form.cls_rows import LocalFrame, toa_rows
from estimators.closed_form.constrained_ls import ConstrainedLS
from estimators.closed_form.gtrs import solve_gtrs
from estimators.closed_form.gtrs_indefinite import solve_gtrs_indefinite_batch
from estimators.closed_form.pseudorange_cls import solve_pseudorange_batch, solve_pseudorange_cls
from estimators.closed_form.pseudorange_two_stage import linearised_correction

__all__ = [
    "Cls",
    "ClsAsPrinted",
    "ClsPaper",
    "ConstrainedLS",
    "LocalFrame",
    "cls_rows",
    "linearised_correction",
    "solve_gtrs",
    "solve_gtrs_indefinite_batch",
    "solve_pseudorange_batch",
    "solve_pseudorange_cls",
    "toa_rows",
]
