r"""The constrained least squares an estimator minimises, exposed for validation (MATH §5, §11).

A closed-form estimator of the Doppler-ToA CLS solves

.. math::

    \min_r \lVert A r - b\rVert^2 \quad\text{s.t.}\quad r_x^2 + r_y^2 - r_z = 0,
    \qquad r = (x, y, x^2 + y^2)

for some rows ``A``, ``b`` (its own weighting, its own frames) in a local frame
``(x, y) = ((x_s, y_s) − origin_m)/scale_m``; with the emitter's height a coordinate,
``r = (x, y, z, x² + y² + z²)`` with ``z = z_s/scale_m``. An estimator that exposes those rows with

.. code-block:: python

    def constrained_ls(self, data: MeasurementSet) -> ConstrainedLS: ...

(:class:`HasConstrainedLS`) can be checked against the exact optimum of the same rows
(:func:`estimators.closed_form.gtrs.solve_gtrs`) and their Shor SDP relaxation
(:func:`estimators.sdp.sdp_cls.solve_sdp_relaxation`) by ``emitterbench validate --estimator NAME``
(:func:`comparison.crosscheck.run_validation`): every candidate it returns must attain the
optimal cost, and in the hard case (MATH §5) it must return both mirror minimisers.

``constrained_ls(data)`` returns exactly the system whose minimisers ``estimate(data)`` claims to
return: for a multi-stage method (the two-stage weighting of ``cls``, MATH §6) the rows of the
final stage, for ``frames="last"`` the rows of the last frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from estimators.closed_form.cls_rows import LocalFrame
from estimators.closed_form.gtrs import constrained_cost
from scenarios.types import MeasurementSet

FloatArray = NDArray[np.float64]

PROTOCOL_METHOD = "constrained_ls"
"""The name of the method of :class:`HasConstrainedLS`."""


def _read_only(value: ArrayLike, name: str, shape: tuple[int | None, ...]) -> FloatArray:
    array = np.array(value, dtype=float)
    if array.ndim != len(shape) or any(
        want is not None and got != want for got, want in zip(array.shape, shape, strict=True)
    ):
        expected = "(" + ", ".join("m" if n is None else str(n) for n in shape) + ")"
        raise ValueError(f"{name}: expected shape {expected}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name}: has NaN or infinite entries")
    array.flags.writeable = False
    return array


@dataclass(frozen=True, slots=True, eq=False)
class ConstrainedLS:
    """``min ‖A r − b‖²`` s.t. ``‖s‖² = r_w`` in a local frame (MATH §5).

    Attributes
    ----------
    A : (m, 3) or (m, 4)
        The stacked rows, weighted as the estimator weights them, over ``r = (x, y, r_z)`` or,
        with the height a coordinate, ``r = (x, y, z, r_w)`` (``z = z_s / scale_m``).
    b : (m,)
    origin_m : (2,)
        World position of the local origin, metres.
    scale_m : float
        Length of one local unit, metres: ``(x, y) = ((x_s, y_s) − origin_m) / scale_m``.
    """

    A: FloatArray
    b: FloatArray
    origin_m: FloatArray
    scale_m: float

    def __post_init__(self) -> None:
        width = np.shape(self.A)[1] if np.ndim(self.A) == 2 and np.shape(self.A)[1] == 4 else 3
        A = _read_only(self.A, "A", (None, width))
        b = _read_only(self.b, "b", (len(A),))
        if len(b) == 0:
            raise ValueError("A: expected at least one row, got none")
        origin = _read_only(self.origin_m, "origin_m", (2,))
        scale = float(self.scale_m)
        if not (np.isfinite(scale) and scale > 0.0):
            raise ValueError(f"scale_m: expected a positive finite length, got {self.scale_m!r}")
        object.__setattr__(self, "A", A)
        object.__setattr__(self, "b", b)
        object.__setattr__(self, "origin_m", origin)
        object.__setattr__(self, "scale_m", scale)

    @classmethod
    def in_frame(cls, A: ArrayLike, b: ArrayLike, frame: LocalFrame) -> ConstrainedLS:
        """The rows ``A``, ``b`` written in ``frame`` (an
        :class:`~estimators.closed_form.cls_rows.LocalFrame`)."""
        return cls(A=A, b=b, origin_m=frame.origin_m, scale_m=frame.scale_m)

    @property
    def frame(self) -> LocalFrame:
        return LocalFrame(origin_m=self.origin_m, scale_m=self.scale_m)

    @property
    def dimension(self) -> int:
        """2, or 3 with the height a coordinate."""
        return self.A.shape[1] - 1

    def to_local(self, xy_m: ArrayLike) -> FloatArray:
        """World points (..., d) in metres to the local frame of the rows."""
        points = np.asarray(xy_m, dtype=float)
        local = points / self.scale_m
        local[..., :2] = self.frame.to_local(points[..., :2])
        return local

    def to_world(self, xy_local: ArrayLike) -> FloatArray:
        """Local points (..., d) to world metres."""
        points = np.asarray(xy_local, dtype=float)
        world = points * self.scale_m
        world[..., :2] = self.frame.to_world(points[..., :2])
        return world

    def cost(self, xy_m: ArrayLike) -> FloatArray:
        """``‖A (s, ‖s‖²) − b‖²`` at world points (..., d): each lifted onto the
        paraboloid."""
        return constrained_cost(self.A, self.b, self.to_local(xy_m))


@runtime_checkable
class HasConstrainedLS(Protocol):
    """An estimator that exposes the constrained least squares its ``estimate`` minimises."""

    def constrained_ls(self, data: MeasurementSet) -> ConstrainedLS: ...
