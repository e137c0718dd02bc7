r"""What the closed forms and the LLS baselines share about one trial's rows (MATH §3, §4, §15).

Unknown ``r = (x_s, y_s, x_s² + y_s²)``. The closed forms build their rows for every trial at
once in :mod:`estimators.closed_form.cls_batch` (one trial's:
:func:`~estimators.closed_form.cls.cls_rows`); here are the pieces the LLS baselines (MATH §9)
and the pseudo-range form use too:

- :class:`LocalFrame`: the frame centred on the track and scaled to order one in which every
  system is solved (it keeps the solve well conditioned);
- :func:`horizontal_speed_mps`, refusing a sample without horizontal motion;
- the squared-range rows (MATH §4, paper eq ``Beq`` with the height term the paper omits),
  ``[−2x_k, −2y_k, 1] r = r_k² − x_k² − y_k² − (z_k − z_s)²`` (:func:`toa_rows`);
- a free linear unknown (an unknown carrier offset δ, whose column in the Doppler rows is
  ``r_k/(γ|v_xy|)``, MATH §15), eliminated exactly by projecting the system onto the
  orthogonal complement of its column (:func:`project_out`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class LocalFrame:
    """``local = (world_xy − origin_m) / scale_m``; heights and ranges divided by ``scale_m``."""

    origin_m: FloatArray
    scale_m: float

    @classmethod
    def fit(cls, position_m: ArrayLike, range_m: ArrayLike) -> LocalFrame:
        """Centred on the samples, scaled by the RMS of their spread and of the ranges."""
        position = np.asarray(position_m, dtype=float)
        origin = position[:, :2].mean(axis=0)
        spread_sq = np.mean(np.sum((position[:, :2] - origin) ** 2, axis=1))
        scale = float(np.sqrt(spread_sq + np.mean(np.asarray(range_m, dtype=float) ** 2)))
        if not scale > 0.0:
            scale = 1.0
        return cls(origin_m=origin, scale_m=scale)

    def positions(self, position_m: ArrayLike) -> FloatArray:
        position = np.asarray(position_m, dtype=float)
        local = position / self.scale_m
        local[..., :2] = (position[..., :2] - self.origin_m) / self.scale_m
        return local

    def to_world(self, xy_local: ArrayLike) -> FloatArray:
        return np.asarray(xy_local, dtype=float) * self.scale_m + self.origin_m

    def to_local(self, xy_m: ArrayLike) -> FloatArray:
        return (np.asarray(xy_m, dtype=float) - self.origin_m) / self.scale_m


def horizontal_speed_mps(velocity_mps: ArrayLike) -> FloatArray:
    """``|v_xy|`` per sample; raises ``ValueError`` on a sample with no horizontal motion."""
    velocity = np.asarray(velocity_mps, dtype=float)
    speed = np.sqrt(velocity[:, 0] * velocity[:, 0] + velocity[:, 1] * velocity[:, 1])
    if (speed <= 0.0).any():
        index = int(np.argmin(speed))
        raise ValueError(
            f"velocity_mps: sample {index} has zero horizontal speed; the Doppler rows of "
            "MATH §3 need a moving UAV (drop hovering samples or their Doppler)"
        )
    return speed


def toa_rows(
    position_m: ArrayLike,
    range_m: ArrayLike,
    emitter_height_m: float,
    *,
    height_term: bool = True,
) -> tuple[FloatArray, FloatArray]:
    """Squared-range rows ``[−2x_k, −2y_k, 1] r = r_k² − x_k² − y_k² − (z_k − z_s)²`` (MATH §4).

    ``height_term=False`` reproduces the paper's ``p_k = d_k² − x_k² − y_k²`` (eq ``Beq`` as
    printed).
    Returns ``A`` (N, 3) and ``b`` (N,).
    """
    position = np.asarray(position_m, dtype=float)
    r = np.asarray(range_m, dtype=float)
    A = np.column_stack([-2.0 * position[:, 0], -2.0 * position[:, 1], np.ones(len(position))])
    b = r**2 - position[:, 0] ** 2 - position[:, 1] ** 2
    if height_term:
        b = b - (position[:, 2] - emitter_height_m) ** 2
    return A, b


def project_out(A: FloatArray, b: FloatArray, columns: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Eliminate free linear unknowns ``t`` from ``min ‖A r + N t − b‖²`` (MATH §15).

    For any ``r`` the best ``t`` is the least-squares solution of ``N t = b − A r``, and the cost
    left is ``‖Q(A r − b)‖²`` with ``Q = I − N N⁺`` the projection off the columns ``N``
    (``(n,)`` or ``(n, m)``): the same GTRS in ``r`` on ``(QA, Qb)``, with the same minimisers.
    A stack of systems (``A`` (t, n, k), ``b`` (t, n), ``columns`` (t, n, m)) is projected
    system by system.
    """
    if np.ndim(b) == 2:
        basis, _ = np.linalg.qr(np.asarray(columns, dtype=float))
        basis_t = np.swapaxes(basis, -1, -2)
        return A - basis @ (basis_t @ A), b - (basis @ (basis_t @ b[..., None]))[..., 0]
    basis, _ = np.linalg.qr(np.asarray(columns, dtype=float).reshape(len(b), -1))
    return A - basis @ (basis.T @ A), b - basis @ (basis.T @ b)
