r"""The paper's trajectory design, corrected (MATH §12; paper Section 4 and Algorithm 1).

After frame ``l`` the emitter estimate ``ŝ`` is known; the velocity ``u`` of frame ``l + 1``
is chosen so that the first sample of the next frame fits the Doppler·range line with zero
residual (paper eqs ``gg``, ``cond1``, ``cond2``):

.. math::

    F = u^\top (p_K + \Delta u - \hat s) \iff u^\top b = d,\qquad
    b = p_{K,xy} - \hat s,\quad d = F - \Delta A^2,\quad |u| = A

(eq ``ueq``), where ``F = f̄_{K+1}/γ`` with ``f̄ = cτf`` in the paper's Doppler sign, i.e.
``F = −r_{K+1} f_{K+1}/γ`` with the physical ``f`` (MATH §1), and ``A`` is the speed.

- Solutions exist iff ``|d| ≤ A|b|``: ``u = (d b ± √(A²|b|² − d²) b⊥)/|b|²`` with
  ``b⊥ = (−b_y, b_x)`` (:func:`circle_roots_mps`; the paper's eq ``ord2`` has ``(1 + b1²)``
  for ``(1 + b1²/b2²)``, the wrong root sign, and divides by ``b2``).
- The two roots are at the same distance from ``ŝ`` at every horizon (``|b + t u|²`` depends
  on ``u`` only through ``uᵀb = d`` and ``|u| = A``): the paper's "nearer to the emitter" rule
  is an exact tie. Algorithm 1 measures ``f_{K+1}`` with the old velocity, so one root is the
  old velocity itself (exactly, noise-free at the truth) and the other the old velocity
  reflected about ``b``. ``tie="turn"`` (default) takes the root farther from the old velocity
  (the turn). ``tie="literal"`` computes both distances of the paper's rule; they are equal in
  exact arithmetic, and rounding must not decide, so distances within a relative 1e-9 count as
  equal and the ``+`` root is taken: the one with ``b × u > 0``, i.e. counter-clockwise about
  ``ŝ``. The literal rule is therefore "circle the estimate counter-clockwise".
- No solution (``|d| > A|b|``): change the speed so that the discriminant vanishes. With
  ``X = A²``, ``d(X)² = X|b|²`` is ``Δ²X² − (2ΔF + |b|²) X + F² = 0`` (the paper's eq ``A2``
  is wrong); take its smallest positive root (:func:`speed_change_squared_mps2`) and
  ``u = d_new b/|b|²`` (eq ``ufin``), whose speed is ``√X``.
- ``V_max``: if that speed exceeds ``V_max`` (or no positive root exists: no speed gives a zero
  residual), fly at ``V_max``: the circle roots when ``|d| ≤ V_max|b|`` with
  ``d = F − ΔV_max²``, else ``u = V_max sign(d) b/|b|``, the velocity of smallest residual at
  that speed. The paper gives no ``V_max``; the default is 20 m/s.

Where ``F`` comes from
----------------------
Algorithm 1 step 3 measures the first sample of the next frame with the *old* velocity before
choosing ``u``. The closed loop predicts it instead of flying an extra sample: with the old
velocity the next sample is at ``p_{K+1} = p_K + Δ v_old`` (the flight's kinematics), and for
every sample ``k`` of the last frame, flown at ``v_old``, ``p_{K+1} − p_k = (t_{K+1} − t_k)
v_old``, so noise-free

.. math::

    F_{K+1} = v_{old}^\top (p_{K+1} - s) = F_k + (t_{K+1} - t_k)\,|v_{old}|^2 .

``doppler_prediction="frame"`` (default) averages this over the K samples of the last frame:
exact without noise, K times smaller variance than one sample, and it needs no sample that is
not yet flown, so the frame structure (K samples per velocity) and the noise stream stay
independent of the planner. ``"last-sample"`` uses the last sample only (the literal
prediction from one measurement). Both need Doppler and ToA (``r = cτ``).

Mirror ambiguity (MATH §7): with two candidates the paper planner uses the returned position
``candidates_m[0]``, as the paper's closed loop would; a wrong side makes ``b`` the mirror
image and the turn the mirror turn, which still resolves the side in the next frame.

Note that MATH §12 (the paper's eq ``gg``) puts sample K+1 at ``p_K + Δu`` with the new
velocity, while the simulator's kinematics put it at ``p_K + Δ v_old``; the rule is
implemented as MATH §12 states it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from scenarios.planners.base import (
    DEFAULT_MAX_SPEED_MPS,
    Plan,
    apply_limits,
    check_candidates,
    check_flight_matches,
    check_speed_limits,
    last_position_m,
    last_velocity_mps,
    max_heading_change_rad,
    nominal_speed_mps,
)
from scenarios.types import FlightPlan, MeasurementSet

FloatArray = NDArray[np.float64]
TieRule = Literal["turn", "literal"]
DopplerPrediction = Literal["frame", "last-sample"]

TIE_RTOL = 1e-9
"""Distances within this relative gap are a tie (the literal rule always ties, MATH §12)."""


# --------------------------------------------------------------------------------------------
# pure functions of MATH §12
# --------------------------------------------------------------------------------------------


def paper_rhs_m2ps(range_m: ArrayLike, doppler_hz: ArrayLike, gamma_per_m: float) -> FloatArray:
    """``F_k = f̄_k/γ = −r_k f_k/γ`` with the physical Doppler ``f_k`` (MATH §1, §12).

    Noise-free, ``F_k = v_kᵀ(p_k − s)``: the paper's ``f̄ = cτ f_d`` with ``f_d = −f``.
    """
    return -np.asarray(range_m, dtype=float) * np.asarray(doppler_hz, dtype=float) / gamma_per_m


def predict_next_rhs_m2ps(
    flight: FlightPlan, data: MeasurementSet, *, method: DopplerPrediction = "frame"
) -> float:
    """``F_{K+1}`` of the first sample of the next frame flown at the old velocity (MATH §12).

    ``F_{K+1} = F_k + (t_{K+1} − t_k)|v_old|²`` for every sample ``k`` of the last frame
    (module docstring): averaged over the frame (``"frame"``) or from the last sample
    (``"last-sample"``).

    Raises
    ------
    ValueError
        Without Doppler or ToA measurements, or for an unknown ``method``.
    """
    if method not in ("frame", "last-sample"):
        raise ValueError(f"doppler_prediction: expected 'frame' or 'last-sample', got {method!r}")
    if data.doppler_hz is None or data.toa_s is None:
        missing = "doppler_hz" if data.doppler_hz is None else "toa_s"
        raise ValueError(
            f"{missing}: the paper planner needs Doppler and ToA measurements "
            "(F = −r f/γ with r = cτ, MATH §12); choose the fisher, orbit or constant planner"
        )
    last = data.frame == data.frame[-1]
    rhs = paper_rhs_m2ps(data.range_m[last], data.doppler_hz[last], data.gamma_per_m)
    velocity = np.asarray(data.velocity_mps[last], dtype=float)
    speed_sq = np.einsum("ij,ij->i", velocity, velocity)
    t_next = float(data.time_s[-1]) + flight.sample_interval_s
    predicted = rhs + (t_next - data.time_s[last]) * speed_sq
    return float(predicted[-1] if method == "last-sample" else predicted.mean())


def circle_roots_mps(b_m: ArrayLike, d_m2ps: float, speed_mps: float) -> FloatArray | None:
    """Both solutions of ``uᵀb = d``, ``|u| = A`` (paper eq ``ueq``, MATH §12), or None.

    ``u = (d b ± √(A²|b|² − d²) b⊥)/|b|²`` with ``b⊥ = (−b_y, b_x)``; the ``+`` root (counter-
    clockwise of ``b``) first. None when ``|d| > A|b|`` (no real solution).

    Returns
    -------
    (2, 2) array or None
    """
    b = np.asarray(b_m, dtype=float)[:2]
    b_norm_sq = float(b @ b)
    discriminant = speed_mps**2 * b_norm_sq - d_m2ps**2
    if discriminant < -1e-12 * speed_mps**2 * b_norm_sq:
        return None
    root = math.sqrt(max(discriminant, 0.0))  # a tangency rounded below zero is a double root
    perpendicular = np.array([-b[1], b[0]])
    return np.stack(
        [
            (d_m2ps * b + root * perpendicular) / b_norm_sq,
            (d_m2ps * b - root * perpendicular) / b_norm_sq,
        ]
    )


def speed_change_squared_mps2(
    rhs_m2ps: float, b_norm_sq_m2: float, sample_interval_s: float
) -> float:
    """The squared speed ``X = A²`` of MATH §12's no-solution branch; NaN if none.

    ``d(X) = F − ΔX`` and the discriminant ``X|b|² − d(X)²`` vanishes where
    ``Δ²X² − (2ΔF + |b|²) X + F² = 0`` (the corrected paper eq ``A2``). Returns the smallest
    positive root (a root below 1e-12 of the larger one, i.e. ``F ≈ 0``, is a zero speed, no
    flight: the larger one is taken). Its discriminant is ``|b|²(|b|² + 4ΔF)``: real roots need
    ``F ≥ −|b|²/(4Δ)``, and then both are ≥ 0 (their product ``F²/Δ²`` and sum are ≥ 0).
    The roots are computed without cancellation: ``q = (B + √disc)/2``, roots ``q/Δ²`` and
    ``F²/q``.
    """
    delta = float(sample_interval_s)
    linear = 2.0 * delta * rhs_m2ps + b_norm_sq_m2
    discriminant = b_norm_sq_m2 * (b_norm_sq_m2 + 4.0 * delta * rhs_m2ps)
    if discriminant < 0.0 or linear <= 0.0:
        return math.nan
    q = 0.5 * (linear + math.sqrt(discriminant))
    larger = q / delta**2
    smaller = rhs_m2ps**2 / q
    if smaller > 1e-12 * larger:  # a root at (rounding-)zero speed is no flight
        return smaller
    return larger if larger > 0.0 else math.nan


def choose_root(
    roots_mps: FloatArray,
    old_velocity_xy_mps: ArrayLike,
    b_m: ArrayLike,
    sample_interval_s: float,
    *,
    tie: TieRule,
) -> tuple[int, dict[str, Any]]:
    """Index of the root MATH §12's tie rule picks, and the distances it compared.

    ``"turn"``: the root farther from the old velocity; ``"literal"``: the root whose next
    position ``p_K + Δu`` is nearer to ``ŝ`` (``|b + Δu|``), an exact tie. A tie (relative gap
    below :data:`TIE_RTOL`) takes the ``+`` root, index 0.
    """
    b = np.asarray(b_m, dtype=float)[:2]
    if tie == "turn":
        old = np.asarray(old_velocity_xy_mps, dtype=float)[:2]
        distance = np.linalg.norm(roots_mps - old, axis=1)
        pick = int(np.argmax(distance))
    else:
        distance = np.linalg.norm(b + sample_interval_s * roots_mps, axis=1)
        pick = int(np.argmin(distance))
    scale = max(float(np.max(distance)), 1e-300)
    tied = abs(float(distance[0] - distance[1])) <= TIE_RTOL * scale
    return (0 if tied else pick), {
        "tie_distance_plus": float(distance[0]),
        "tie_distance_minus": float(distance[1]),
        "tied": bool(tied),
    }


def paper_velocity_mps(
    b_m: ArrayLike,
    rhs_m2ps: float,
    sample_interval_s: float,
    speed_mps: float,
    old_velocity_xy_mps: ArrayLike,
    *,
    max_speed_mps: float = DEFAULT_MAX_SPEED_MPS,
    tie: TieRule = "turn",
) -> tuple[FloatArray, str, dict[str, Any]]:
    """The next horizontal velocity of MATH §12, its branch and diagnostics.

    Parameters
    ----------
    b_m : (2,)
        ``b = p_{K,xy} − ŝ``, not zero.
    rhs_m2ps : float
        ``F = f̄_{K+1}/γ`` (paper sign; :func:`predict_next_rhs_m2ps`).
    sample_interval_s : float
        Δ.
    speed_mps : float
        The speed ``A`` to keep if possible (> 0); capped at ``max_speed_mps`` first.
    old_velocity_xy_mps : (2,)
        The last frame's horizontal velocity (for ``tie="turn"``).
    max_speed_mps : float
        V_max.
    tie : {"turn", "literal"}

    Returns
    -------
    velocity : (2,)
    branch : str
        ``"circle"`` (speed kept), ``"speed-change"`` (eq ``A2``, then eq ``ufin``),
        ``"vmax-circle"`` or ``"vmax-along-b"`` (the V_max rule).
    diagnostics : dict
    """
    b = np.asarray(b_m, dtype=float)[:2]
    b_norm_sq = float(b @ b)
    delta = float(sample_interval_s)
    speed = min(float(speed_mps), float(max_speed_mps))
    d = rhs_m2ps - delta * speed**2  # eq cond2 / ueq
    diagnostics: dict[str, Any] = {
        "rhs_m2ps": rhs_m2ps,
        "d_m2ps": d,
        "b_norm_m": math.sqrt(b_norm_sq),
    }
    roots = circle_roots_mps(b, d, speed)
    if roots is not None:
        index, compared = choose_root(roots, old_velocity_xy_mps, b, delta, tie=tie)
        return roots[index], "circle", {**diagnostics, **compared, "speed_mps": speed}
    speed_sq = speed_change_squared_mps2(rhs_m2ps, b_norm_sq, delta)
    diagnostics["speed_change_mps"] = math.sqrt(speed_sq) if math.isfinite(speed_sq) else math.nan
    if math.isfinite(speed_sq) and math.sqrt(speed_sq) <= max_speed_mps:
        d_new = rhs_m2ps - delta * speed_sq  # eq dnew, corrected
        velocity = d_new * b / b_norm_sq  # eq ufin
        return velocity, "speed-change", {**diagnostics, "speed_mps": math.sqrt(speed_sq)}
    d_max = rhs_m2ps - delta * max_speed_mps**2
    roots = circle_roots_mps(b, d_max, max_speed_mps)
    if roots is not None:
        index, compared = choose_root(roots, old_velocity_xy_mps, b, delta, tie=tie)
        return roots[index], "vmax-circle", {**diagnostics, **compared, "speed_mps": max_speed_mps}
    velocity = max_speed_mps * math.copysign(1.0, d_max) * b / math.sqrt(b_norm_sq)
    return velocity, "vmax-along-b", {**diagnostics, "speed_mps": max_speed_mps}


# --------------------------------------------------------------------------------------------
# the planner
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class PaperPlanner:
    """The paper's zero-residual heading rule, corrected (MATH §12; module docstring).

    Parameters
    ----------
    tie : {"turn", "literal"}
        ``"turn"``: the root farther from the old velocity; ``"literal"``: the paper's "nearer
        to the emitter", an exact tie broken towards the counter-clockwise (``+``) root.
    doppler_prediction : {"frame", "last-sample"}
        How ``F_{K+1}`` is predicted from the last frame (module docstring).
    speed_mps : float or None
        The speed ``A``; None: the first frame's speed (the paper's fixed ``A_v``).
    max_speed_mps : float
        V_max (default 20 m/s; the paper gives none).
    max_turn_rate_dps : float or None
        Optional turn-rate limit, applied after the rule (heading clipped, speed kept).
    """

    name: ClassVar[str] = "paper"

    tie: TieRule = "turn"
    doppler_prediction: DopplerPrediction = "frame"
    speed_mps: float | None = None
    max_speed_mps: float = DEFAULT_MAX_SPEED_MPS
    max_turn_rate_dps: float | None = None

    def __post_init__(self) -> None:
        if self.tie not in ("turn", "literal"):
            raise ValueError(f"tie: expected 'turn' or 'literal', got {self.tie!r}")
        if self.doppler_prediction not in ("frame", "last-sample"):
            raise ValueError(
                "doppler_prediction: expected 'frame' or 'last-sample', "
                f"got {self.doppler_prediction!r}"
            )
        check_speed_limits(
            max_speed_mps=self.max_speed_mps,
            speed_mps=self.speed_mps,
            max_turn_rate_dps=self.max_turn_rate_dps,
        )

    def plan(
        self,
        flight: FlightPlan,
        candidates_m: ArrayLike,
        data: MeasurementSet,
        *,
        covariance_m2: ArrayLike | None = None,
        rng: np.random.Generator | None = None,
    ) -> Plan:
        """The next frame's velocity by MATH §12 from ``candidates_m[0]`` (the covariance is unused).

        Raises
        ------
        ValueError
            Data without Doppler or ToA, a zero nominal speed, or an estimate directly below
            the UAV's last position (``b = 0``: the rule is undefined there).
        """
        check_flight_matches(flight, data)
        estimate = check_candidates(candidates_m)[0]
        position = last_position_m(flight)
        b = position[:2] - estimate
        if float(np.hypot(*b)) <= 1e-9 * max(float(np.hypot(*position[:2])), 1.0):
            raise ValueError(
                "candidates_m: the estimate lies directly below the UAV's last position "
                "(b = p_K − ŝ = 0), where the rule of MATH §12 is undefined; hold the last "
                "velocity or use another planner for this frame"
            )
        speed = nominal_speed_mps(flight, self.speed_mps)
        old = last_velocity_mps(flight)
        rhs = predict_next_rhs_m2ps(flight, data, method=self.doppler_prediction)
        velocity_xy, branch, diagnostics = paper_velocity_mps(
            b,
            rhs,
            flight.sample_interval_s,
            speed,
            old[:2],
            max_speed_mps=self.max_speed_mps,
            tie=self.tie,
        )
        velocity, acted = apply_limits(
            velocity_xy,
            old,
            max_speed_mps=self.max_speed_mps,
            max_heading_change=max_heading_change_rad(flight, self.max_turn_rate_dps),
        )
        message = branch + "".join(f", limited by {name}" for name in acted)
        return Plan(
            planner=self.name,
            velocity_mps=velocity,
            message=message,
            diagnostics={"branch": branch, **diagnostics},
        )
