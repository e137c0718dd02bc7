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
    sum ``Σ_m w_m exp(j u_m θ)`` at the returned ``θ``.
    """
    theta = np.array(start, dtype=float)
    slope_rates = 1j * rates
    curvature_rates = -(rates**2)
    for _ in range(steps):
        terms = weights * np.exp(1j * theta[:, None] * rates)
        value = terms.sum(axis=-1)
        first = (terms * slope_rates).sum(axis=-1)
        second = (terms * curvature_rates).sum(axis=-1)
        slope = 2.0 * (np.conj(value) * first).real
        curvature = 2.0 * (np.abs(first) ** 2 + (np.conj(value) * second).real)
        concave = curvature < 0.0
        newton = -slope / np.where(concave, curvature, -1.0)
        step = np.where(concave, newton, 0.5 * step_limit * np.sign(slope))
        theta += np.clip(step, -step_limit, step_limit)
    value = (weights * np.exp(1j * theta[:, None] * rates)).sum(axis=-1)
    return theta, value


def parabola_vertex(left: np.ndarray, centre: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Offset in ``[-1/2, 1/2]`` grid steps of the vertex of the parabola through three equally
    spaced values with the largest in the centre (docs/math.md §19); 0 where they are flat."""
    denominator = left - 2.0 * centre + right
    flat = denominator == 0.0
    offset = 0.5 * (left - right) / np.where(flat, 1.0, denominator)
    return np.clip(np.where(flat, 0.0, offset), -0.5, 0.5)
