r"""The one refinement both estimators share: Newton steps to the maximum of a periodogram
(docs/math.md §19).

Both the tone's frequency and the burst's delay maximise a function of one parameter ``θ`` of
the form

.. math::

    P(\theta) = \Big|\sum_m w_m\, e^{\,j u_m \theta}\Big|^2

(the frequency: ``w`` the samples, ``u`` minus the centred sample index, ``θ`` in rad/sample;
the delay: ``w`` the cross-spectrum, ``u`` 2π times the bin frequencies, ``θ`` in samples).
:func:`newton_to_peak` takes a few Newton steps on the exact ``P`` from a start near the peak,
every row (burst) at once.
"""

from __future__ import annotations

import numpy as np

NEWTON_STEPS = 3
"""Newton steps from the interpolated grid peak: the start is within a few thousandths of the
main lobe's width, so three quadratic steps reach rounding (docs/math.md §19)."""


def newton_to_peak(
    weights: np.ndarray, rates: np.ndarray, start: np.ndarray, step_limit: float, steps: int
) -> tuple[np.ndarray, np.ndarray]:
    """``steps`` Newton steps on ``P(θ) = |Σ_m w_m exp(j u_m θ)|²`` per row (docs/math.md §19).

    ``weights`` is ``(n, M)`` complex, ``rates`` the ``(M,)`` real ``u``, ``start`` the ``(n,)``
    starting ``θ``. A step is clipped to ``±step_limit`` (the coarse grid's spacing); where
    ``P`` is not concave the step is ``step_limit / 2`` uphill. Returns ``θ`` and the complex
    sum ``A = Σ_m w_m exp(j u_m θ)`` at the returned ``θ``, with ``P' = 2 Re(A* A')`` and
    ``P'' = 2 (|A'|² + Re(A* A''))``, ``A' = Σ j u w e^{juθ}``, ``A'' = −Σ u² w e^{juθ}``.

    Written in real arithmetic: numpy's complex product takes a vector loop (with fused
    multiply-adds) or a scalar one depending on the arrays' alignment, so its bits would depend
    on where the arrays lie; real products and sums do not.
    """
    theta = np.array(start, dtype=float)
    weight_re, weight_im = weights.real, weights.imag
    for _ in range(steps):
        re, im = rotated(weight_re, weight_im, theta[:, None] * rates)
        value_re, value_im = re.sum(axis=-1), im.sum(axis=-1)
        first_re, first_im = -(im * rates).sum(axis=-1), (re * rates).sum(axis=-1)
        square_rates = rates * rates
        second_re, second_im = -(re * square_rates).sum(axis=-1), -(im * square_rates).sum(axis=-1)
        slope = 2.0 * (value_re * first_re + value_im * first_im)
        curvature = 2.0 * (
            first_re * first_re + first_im * first_im + value_re * second_re + value_im * second_im
        )
        concave = curvature < 0.0
        newton = -slope / np.where(concave, curvature, -1.0)
        step = np.where(concave, newton, 0.5 * step_limit * np.sign(slope))
        theta += np.clip(step, -step_limit, step_limit)
    re, im = rotated(weight_re, weight_im, theta[:, None] * rates)
    value = np.empty(theta.shape, dtype=complex)
    value.real, value.imag = re.sum(axis=-1), im.sum(axis=-1)
    return theta, value


def rotated(
    real: np.ndarray, imag: np.ndarray, phase_rad: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Real and imaginary parts of ``(real + j imag) · exp(j phase)``, in real arithmetic."""
    cos, sin = np.cos(phase_rad), np.sin(phase_rad)
    return real * cos - imag * sin, real * sin + imag * cos


def parabola_vertex(left: np.ndarray, centre: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Offset in ``[-1/2, 1/2]`` grid steps of the vertex of the parabola through three equally
    spaced values with the largest in the centre (docs/math.md §19); 0 where they are flat."""
    denominator = left - 2.0 * centre + right
    flat = denominator == 0.0
    offset = 0.5 * (left - right) / np.where(flat, 1.0, denominator)
    return np.clip(np.where(flat, 0.0, offset), -0.5, 0.5)
