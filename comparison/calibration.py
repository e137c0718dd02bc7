r"""An estimator of known efficiency and bias: the suite's check on its own verdicts.

:class:`KnownEfficiency` is told where the emitter is (``emitter_m``: the comparison hands no
estimator the truth) and returns

.. math::

    \hat s = s + \sigma\,L z + \beta \sqrt{\operatorname{tr}\mathrm{CRLB}}\;u,
    \qquad z \sim \mathcal N(0, I_2),\quad L L^\top = \mathrm{CRLB},

with ``σ = scale``, ``β = bias_ratio`` and ``u`` a principal axis of the CRLB (MATH §8) at the
truth, for the modalities and frames it declares (ToA and Doppler, every frame), the nuisance
parameters of the data eliminated (MATH §15). Its efficiency is exactly
``√(σ² + β²)`` and its bias ``β`` √CRLB, so a comparison run of it tells how often the verdicts
(:mod:`comparison.verdicts`) say ``attains`` for an efficient unbiased estimator (``σ = 1``,
``β = 0``) and whether a biased one that matches the bound's RMSE (``σ = 0.8``, ``β = 0.6``:
efficiency exactly 1) is ever said to attain it. The built-in experiment ``calibration``
runs it (``emitterbench run calibration``); docs/math.md §16 gives the
measured counts.

It is not an estimator of the emitter: it is given the answer, and only the experiments
whose every point has that emitter (an SNR sweep of a fixed geometry) can run it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from estimators.base import Capabilities, Estimate, check_rng, check_side_prior
from scenarios.fields import finite
from scenarios.fisher import fisher_information, inverse_symmetric
from scenarios.types import MeasurementSet

AXES = ("major", "minor")
"""The principal axes of the CRLB a bias can lie along, largest variance first."""


@dataclass(frozen=True, kw_only=True)
class KnownEfficiency:
    """The truth plus ``N(0, scale² CRLB)`` plus a bias of ``bias_ratio`` √trace(CRLB).

    Parameters
    ----------
    emitter_m : (x, y)
        The true emitter position, metres: what the error is drawn around.
    scale : float
        ``σ``: the error's standard deviation in units of the CRLB's (1: efficient).
    bias_ratio : float
        ``β``: the bias's length in units of √trace(CRLB) (0: unbiased).
    bias_axis : {"major", "minor"}
        The principal axis of the CRLB the bias lies along.
    """

    name: ClassVar[str] = "known-efficiency"
    requires: ClassVar[frozenset[str]] = frozenset({"toa", "doppler"})

    emitter_m: tuple[float, float] = (35.0, 15.0)
    scale: float = 1.0
    bias_ratio: float = 0.0
    bias_axis: str = "major"

    def __post_init__(self) -> None:
        if self.emitter_m is None:
            raise ValueError("emitter_m: the true emitter position (x, y) in metres is needed")
        check_side_prior(self.emitter_m, field="emitter_m")
        for field in ("scale", "bias_ratio"):
            value = getattr(self, field)
            if isinstance(value, bool) or finite(value, field) < 0:
                raise ValueError(f"{field}: expected a finite number >= 0, got {value!r}")
        if self.bias_axis not in AXES:
            raise ValueError(f"bias_axis: expected one of {AXES}, got {self.bias_axis!r}")

    def capabilities(self) -> Capabilities:
        return Capabilities(
            modalities=self.requires,
            unknowns=frozenset({"carrier_offset_hz", "emission_time_s"}),
        )

    def estimate(self, data: MeasurementSet, *, rng: np.random.Generator | None = None) -> Estimate:
        """The truth moved by a draw of the error (module docstring)."""
        rng = check_rng(rng)
        if rng is None:
            raise ValueError("rng: known-efficiency draws its error from rng; pass a Generator")
        truth = np.asarray(self.emitter_m, dtype=float)
        crlb = inverse_symmetric(fisher_information(data, truth, sorted(self.requires)))
        if not np.all(np.isfinite(crlb)):
            return Estimate.failed(self.name, "singular Fisher information: no CRLB to draw from")
        variances, axes = np.linalg.eigh(crlb)
        axis = axes[:, -1] if self.bias_axis == "major" else axes[:, 0]
        error = self.scale * np.linalg.cholesky(crlb) @ rng.standard_normal(2)
        error += self.bias_ratio * math.sqrt(float(np.trace(crlb))) * axis
        position = truth + error
        return Estimate(
            estimator=self.name,
            position_m=position,
            candidates_m=position[None, :],
            ambiguous=False,
            covariance_m2=self.scale**2 * crlb,
            diagnostics={"crlb_major_m2": float(variances[-1])},
        )
