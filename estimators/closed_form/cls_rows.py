r"""The rows of the Doppler-ToA constrained least squares (MATH §3, §4), one trial written plainly.

Unknown ``r = (x_s, y_s, x_s² + y_s²)``. Every function here is pure numpy, vectorised over
samples, and works in whatever length unit its inputs use, usually a local frame centred on the
track and scaled to order one (:class:`LocalFrame`), which keeps the solve well conditioned.
The closed-form estimators build the same rows for every trial at once, whitened (MATH §6), in
:mod:`estimators.closed_form.cls_batch`; these one-trial forms are what docs/math.md prints and
checks step by step, what the LLS baselines solve, and the tests' independent account of the
rows.

- Doppler·range rows (MATH §3, paper eqs ``gls``-``lineq`` corrected): multiplying the Doppler
  model by the ToA range removes the square root; with the physical sign and known ``z_s``,
  ``v_kᵀ s_xy = v_kᵀ p_k + r_k f_k/γ − v_z z_s``. Divided by the horizontal speed the row is
  ``[v̂ᵀ, 0] r`` with ``v̂`` the unit horizontal direction.
- Squared-range rows (MATH §4, paper eq ``Beq`` with the height term the paper omits):
  ``[−2x_k, −2y_k, 1] r = r_k² − x_k² − y_k² − (z_k − z_s)²``.
- A free linear unknown (an unknown carrier offset δ, whose column in the Doppler rows is
  ``r_k/(γ|v_xy|)``, MATH §15) is eliminated exactly by projecting the system onto the
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
    speed = np.linalg.norm(np.asarray(velocity_mps, dtype=float)[:, :2], axis=1)
    if np.any(speed <= 0.0):
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


def doppler_rows(
    position_m: ArrayLike,
    velocity_mps: ArrayLike,
    range_m: ArrayLike,
    doppler_hz: ArrayLike,
    gamma_per_m: float,
    emitter_height_m: float,
) -> tuple[FloatArray, FloatArray]:
    """One Doppler·range row per sample, ``[v̂_kᵀ, 0] r = (v_kᵀp_k + r_k f_k/γ − v_z z_s)/|v_xy|``.

    MATH §3 (physical Doppler sign) and §6 (one row per sample). Returns ``A`` (N, 3), ``b`` (N,).
    """
    position = np.asarray(position_m, dtype=float)
    velocity = np.asarray(velocity_mps, dtype=float)
    speed = horizontal_speed_mps(velocity)
    rhs = (
        np.einsum("ij,ij->i", velocity, position)
        + np.asarray(range_m) * np.asarray(doppler_hz) / gamma_per_m
        - velocity[:, 2] * emitter_height_m
    )
    A = np.column_stack([velocity[:, :2] / speed[:, None], np.zeros(len(position))])
    return A, rhs / speed


def frame_mean_rows(
    frame: ArrayLike, A: FloatArray, b: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """The mean row of each frame: MATH §3's one projected Doppler row per frame.

    Within a straight frame every Doppler row has the same left side, so the least squares of
    paper eq ``glsf`` fixes only their mean: ``[v̂ᵀ, 0] r = mean_k(...)``.
    Returns ``A`` (n_frames, 3) and ``b`` (n_frames,), frames in ascending order.
    """
    frame = np.asarray(frame)
    labels, index, counts = np.unique(frame, return_inverse=True, return_counts=True)
    A_mean = np.zeros((len(labels), A.shape[1]))
    b_mean = np.zeros(len(labels))
    np.add.at(A_mean, index, A)
    np.add.at(b_mean, index, b)
    return A_mean / counts[:, None], b_mean / counts


def paper_row_scale_m2ps2(frame: ArrayLike, velocity_mps: ArrayLike) -> FloatArray:
    """``K|v|²`` of each frame: the scale of the paper's projected Doppler row (MATH §3).

    The paper's rank-one system ``A s = c₁`` has ``A = Σ_k v_k v_kᵀ = K v vᵀ``; projected on
    ``v̂`` it is the unit row of :func:`frame_mean_rows` times ``K|v|²`` (horizontal speed),
    in m²/s². In an unweighted least squares this scale is the row's weight. Returns
    (n_frames,), frames in ascending order.
    """
    frame = np.asarray(frame)
    _, first, counts = np.unique(frame, return_index=True, return_counts=True)
    speed_sq = np.sum(np.asarray(velocity_mps, dtype=float)[first, :2] ** 2, axis=1)
    return counts * speed_sq


def doppler_rows_as_printed(
    frame: ArrayLike,
    position_m: ArrayLike,
    velocity_mps: ArrayLike,
    range_m: ArrayLike,
    doppler_hz: ArrayLike,
    gamma_per_m: float,
) -> tuple[FloatArray, FloatArray]:
    """The paper's Doppler line as printed: the first row of its rank-one system, per frame.

    Paper eqs ``rr1``-``lineq``: ``k1 x_s + k2 y_s = c11`` with ``k1 = Σ v_k1 v_k1``,
    ``k2 = Σ v_k1 v_k2`` (printed as ``k1`` twice) and
    ``c11 = −(1/γ) Σ f̄_k v_k1 + Σ (v_kᵀp_k) v_k1``, ``f̄_k = c τ_k f_k`` in the paper's sign
    (``f_paper = −f``). All zeros when ``v_x = 0``; no height correction. Kept only to show
    what the printed formulas cost (MATH §3).
    """
    velocity = np.asarray(velocity_mps, dtype=float)
    position = np.asarray(position_m, dtype=float)
    f_bar_paper = np.asarray(range_m) * -np.asarray(doppler_hz)  # f̄ = c τ f_paper
    v1 = velocity[:, 0]
    rows = np.column_stack([v1 * v1, v1 * velocity[:, 1], np.zeros(len(v1))])
    rhs = -f_bar_paper * v1 / gamma_per_m + np.einsum("ij,ij->i", velocity, position) * v1
    labels, index = np.unique(np.asarray(frame), return_inverse=True)
    A = np.zeros((len(labels), 3))
    b = np.zeros(len(labels))
    np.add.at(A, index, rows)
    np.add.at(b, index, rhs)
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
