"""The estimator conformance suite: small named checks that every estimator must pass.

Like scikit-learn's ``sklearn.utils.estimator_checks``, the suite ships inside the package so
that a plug-in author can run it on a new estimator::

    from estimators.checks import check_estimator
    check_estimator(MyEstimator())            # raises AssertionError listing every failure

or, in a pytest module, one test per (estimator, check) pair::

    from estimators.checks import parametrize_with_checks

    @parametrize_with_checks([MyEstimator(), MyEstimator(step_m=0.5)])
    def test_conformance(estimator, check):
        check(estimator)

A check is a function ``check_<what>(estimator)`` that returns nothing or raises
``AssertionError`` whose message names the problem and the fix. :func:`estimator_checks`
yields the checks that apply: the batch check only when the estimator has ``estimate_batch``,
the streaming checks only for a :class:`~estimators.base.SequentialEstimator`, the unit
check only when it claims ``unit_invariant`` and the two-headings check only when it uses
every frame. What an estimator uses and claims is read from its declared
:class:`~estimators.base.Capabilities` (:func:`~estimators.base.capabilities_of`), and the
checks hold it to that declaration. A check that an estimator fails *by design* is recorded
with its reason in ``expected_failed_checks={"check_name": "reason"}``; it then must fail (a
strict xfail), so the record cannot go stale.

Reference problems (:class:`ReferenceProblem`, like cvxpy's ``sdp_1``)
    Geometries whose optimum is known and recorded: on noise-free data the minimisers of
    every consistent cost are the emitter, and on one straight frame also its mirror image
    across the track (MATH §7). The fixed ones (:data:`REFERENCE_PROBLEMS`):

    - ``paper-1m``: the paper's straight frame (MATH §14); optima (35, ±15) m;
    - ``turn``: the same emitter, east then north; optimum (35, 15) m;
    - ``far-turn``: kilometres from the origin, emitter (2400, −1300) m, 433.92 MHz, two
      headings; optimum (2400, −1300) m;
    - ``climb``: climbing and descending frames (``v_z ≠ 0``), emitter (−60, 80) m at a
      known height of 25 m, 2.4 GHz; optimum (−60, 80) m;
    - ``climb-straight``: the first, climbing frame of ``climb``; optima (−60, 80) m and
      its mirror (93.6, −35.2) m.

    Two more are drawn at random on every run of the suite (``random-straight``, one
    straight frame, and ``random-turn``, two or three headings): an emitter anywhere within
    5 km of the origin with a known height, a flight 25-120 m to its side, random speed,
    heading, climb rate, carrier, sampling and noise levels (:func:`random_problem`). Their
    seed, the *check seed*, comes from OS entropy once per process, or from the environment
    variable ``EMITTERBENCH_CHECK_SEED``; every message about a random problem names it, and
    ``EMITTERBENCH_CHECK_SEED=<seed> pytest ...`` replays the failure (the check seed also
    draws the translation, rotation and reflection of the equivariance check). A random
    emitter lies within 150 m of the mean UAV position (as every fixed one does) and at
    least 20 m from every frame's track, and a random problem has an RMS slant range of at
    least 65 m (the fixed ones: 60.7 m on ``turn`` to 134 m on ``far-turn``), so that its
    tolerance cap is never below the fixed problems'.

    *Noise-free* data are exact measurements labelled with the σ's of
    :data:`NOISE_FREE_SNR_DB` = 100 dB (MATH §2), the limit of vanishing noise, so that
    weights and de-biasing factors that depend on σ are those of noise-free data. *Noisy*
    data are seeded trials (:data:`DATA_SEED`). Every call gets freshly built data, so that
    a check never sees what another call did to them.

Tolerances
    A noise-free candidate is *exact* within :data:`EXACT_TOLERANCE_M` = 1e-6 m, or
    :data:`EXACT_RTOL` = 1e-9 of the problem's extent (its largest coordinate) when that is
    larger (rounding far from the origin). An iterative or grid method may loosen it only
    by declaring ``Capabilities(noise_free_tolerance_m=..., tolerance_reason="...")``, with
    a non-empty reason, and never beyond :data:`MAX_NOISE_FREE_TOLERANCE` = 1e-3 of the
    problem's RMS UAV-emitter slant range (6 cm on ``paper-1m``); a looser declaration fails
    ``check_capabilities_declared``, and the exact checks use the cap instead. A class
    attribute ``noise_free_tolerance_m`` is not read. Batch and streaming results must agree
    with ``estimate`` within :data:`AGREEMENT_TOLERANCE_M` (or the honoured declared
    tolerance, if looser); answers on moved or rescaled geometries within the noise-free
    tolerance (rounding at the moved geometry's largest coordinate included). A candidate
    *reproduces* the noise-free data when the Gauss-Newton step from it to the data
    (whitened by the σ's) is within the tolerance and leaves at most
    :data:`MISFIT_LIMIT` σ RMS unexplained. Noisy answers must be within
    :data:`CRLB_FACTOR` = 5 times the Cramér-Rao bound √trace(J⁻¹) (MATH §8) of the
    modalities and frames the estimator declares, side resolved (nearest candidate), over
    :data:`CRLB_TRIALS` seeded trials at :data:`CRLB_SNR_DB` = 30 dB. Diagnostics whose key
    names a time (``*time*_s``, e.g. ``solve_time_s``) are exempt from the equality checks.
"""

from __future__ import annotations

import copy
import functools
import importlib
import inspect
import json
import math
import os
import pickle
import re
import secrets
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, fields, is_dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from estimators.base import Capabilities, Estimate, capabilities_of
from scenarios import measurement_model as model
from scenarios.catalog import CATALOG, get_scenario, heading_velocities_mps
from scenarios.geometry import mirror_across_line, straight_track_line
from scenarios.simulate import noise_free, simulate, simulate_trials
from scenarios.types import (
    MODALITIES,
    SPEED_OF_LIGHT_MPS,
    FlightPlan,
    MeasurementBatch,
    MeasurementSet,
    NoiseSigmas,
    RssModel,
    Scenario,
)

Check = Callable[[Any], None]
FloatArray = NDArray[np.float64]

EXACT_TOLERANCE_M = 1e-6
"""Default distance (m) from an optimum within which a noise-free candidate counts as exact."""

EXACT_RTOL = 1e-9
"""The default tolerance relative to a problem's extent, when that is larger (rounding)."""

MAX_NOISE_FREE_TOLERANCE = 1e-3
"""Cap on a declared ``noise_free_tolerance_m``, relative to the RMS slant range (6 cm on
``paper-1m``): a noise-free answer further off is not exact, whatever is declared."""

AGREEMENT_TOLERANCE_M = 1e-6
"""Distance (m) within which batch or streaming positions must equal ``estimate``'s."""

MISFIT_LIMIT = 1.0
"""Unexplained whitened residual (σ, RMS) allowed after the Gauss-Newton step to the data."""

NOISE_FREE_SNR_DB = 100.0
"""The SNR whose σ's label the noise-free reference data (MATH §2): vanishing noise."""

NOISY_SNR_DB = 10.0
"""The SNR of the noisy trials of the behavioural checks (determinism, batch, equivariance)."""

CRLB_SNR_DB = 30.0
"""The SNR of the trials compared with the Cramér-Rao bound."""

CRLB_TRIALS = 24
"""Seeded trials per problem in the comparison with the Cramér-Rao bound."""

CRLB_FACTOR = 5.0
"""The side-resolved RMSE may be at most this multiple of √trace(J⁻¹) (MATH §8)."""

DATA_SEED = 20_240_601
"""Seed of the noisy trials (fixed: the noisy checks are reproducible)."""

RNG_SEED = 7
"""Seed of the tie-breaking generators the checks pass as ``rng``."""

CHECK_SEED_ENV = "EMITTERBENCH_CHECK_SEED"
"""Environment variable that fixes the check seed (random problems, moved geometries)."""

REFERENCE_PROBLEMS = ("paper-1m", "turn", "far-turn", "climb", "climb-straight")
"""The fixed reference problems; :data:`RANDOM_PROBLEMS` are drawn from the check seed."""

RANDOM_PROBLEMS = ("random-straight", "random-turn")
"""The reference problems drawn anew on every run (from :func:`check_seed`)."""

REFERENCE_SCENARIOS = ("paper-1m", "turn", "orbit")
"""Named scenarios of :mod:`scenarios.catalog` that :func:`reference_data` also accepts."""

FIELD_OF_MODALITY = {"doppler": "doppler_hz", "toa": "toa_s", "rss": "rss_dbm"}
"""The :class:`~scenarios.types.MeasurementSet` field of each modality."""

_FIELD_PREFIX = re.compile(r"^[A-Za-z_][\w.\[\]]*(?:(?:, |/)[A-Za-z_][\w.\[\]]*)*: ")

_PROCESS_SEED = secrets.randbits(32)


def check_seed() -> int:
    """The seed of this run's random problems and moved geometries.

    ``EMITTERBENCH_CHECK_SEED`` when set (to replay a failure), else one drawn from OS
    entropy when this module was imported (the same for the whole process).
    """
    text = os.environ.get(CHECK_SEED_ENV, "").strip()
    if not text:
        return _PROCESS_SEED
    try:
        return int(text)
    except ValueError:
        raise ValueError(
            f"{CHECK_SEED_ENV}: expected a whole number (the seed a failure message names), "
            f"got {text!r}"
        ) from None


# --------------------------------------------------------------------------------------------
# reference problems
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class ReferenceProblem:
    """A geometry with a known, recorded optimum (cvxpy's ``sdp_1``).

    Attributes
    ----------
    name : str
    scenario : Scenario
        Emitter, flight and constants; it simulates Doppler, ToA and RSS.
    optima_m : (n, 2)
        Every minimiser on noise-free data from all frames: the emitter, and on one straight
        frame also its mirror image across the track (MATH §7).
    source : str
        Where the optimum comes from.
    seed : int or None
        The check seed a random problem was drawn from (None: a fixed problem).
    """

    name: str
    scenario: Scenario
    optima_m: FloatArray
    source: str
    seed: int | None = None

    def __post_init__(self) -> None:
        optima = np.array(self.optima_m, dtype=float).reshape(-1, 2)
        optima.flags.writeable = False
        object.__setattr__(self, "optima_m", optima)

    @property
    def label(self) -> str:
        """The name as messages show it; a random problem's says how to replay it."""
        if self.seed is None:
            return f"'{self.name}'"
        return f"'{self.name}' (check seed {self.seed}; replay with {CHECK_SEED_ENV}={self.seed})"

    @property
    def emitter_m(self) -> FloatArray:
        return np.array(self.scenario.emitter_m, dtype=float)

    @property
    def straight(self) -> bool:
        flight = self.scenario.flight
        line = straight_track_line(flight.sample_positions_m(), flight.sample_velocities_mps())
        return line is not None

    def data(self, *, snr_db: float | None = None, seed: int = DATA_SEED) -> MeasurementSet:
        """Fresh measurements without the truth: noise-free (None) or one trial at ``snr_db``."""
        if snr_db is None:
            built = noise_free(self.scenario, snr_db=NOISE_FREE_SNR_DB)
        else:
            built = simulate(self.scenario, snr_db=snr_db, seed=seed)
        return built.without_truth()

    def trials(self, *, snr_db: float, n_trials: int, seed: int = DATA_SEED) -> MeasurementBatch:
        """``n_trials`` seeded noisy trials (``SeedSequence(seed).spawn``), truth removed."""
        seeds = np.random.SeedSequence(seed).spawn(n_trials)
        batch = simulate_trials(self.scenario, snr_db=snr_db, seeds=seeds)
        return replace(batch, geometry=batch.geometry.without_truth())

    def rms_range_m(self) -> float:
        """RMS slant range from the UAV samples to the emitter (m)."""
        data = noise_free(self.scenario)
        return float(np.sqrt(np.mean(data.range_m**2)))

    def extent_m(self) -> float:
        """The largest horizontal coordinate of the samples and the emitter (m)."""
        positions = self.scenario.flight.sample_positions_m()[:, :2]
        return float(max(np.max(np.abs(positions)), np.max(np.abs(self.emitter_m))))

    def optima_for(self, frames: str | tuple[int, ...]) -> FloatArray:
        """The optima on the noise-free data of ``frames`` (an estimator's declared frames).

        Every frame: :attr:`optima_m`. A subset that is one straight frame: the emitter and its
        mirror image across that frame's track; any other subset: the emitter.
        """
        if frames == "all":
            return self.optima_m
        used = select_frames(noise_free(self.scenario), frames)
        if used is None:
            return self.optima_m
        line = straight_track_line(used.position_m, used.velocity_mps)
        if line is None:
            return self.emitter_m[None, :]
        return np.vstack([self.emitter_m, mirror_across_line(self.emitter_m, *line)])


def select_frames(data: MeasurementSet, frames: str | tuple[int, ...]) -> MeasurementSet | None:
    """The samples of the declared ``frames`` ("all", "last" or indices); None if none is there."""
    if isinstance(frames, str):
        return data.select_frames(frames)
    mask = np.isin(data.frame, np.asarray(frames, dtype=int))
    return data.take(mask) if mask.any() else None


def _far_turn_scenario() -> Scenario:
    return Scenario(
        name="far-turn",
        emitter_m=[2400.0, -1300.0],
        flight=FlightPlan(
            start_position_m=[2280.0, -1390.0, 80.0],
            frame_velocities_mps=heading_velocities_mps(12.0, [20.0, 110.0]),
            samples_per_frame=10,
            sample_interval_s=0.5,
        ),
        carrier_hz=433.92e6,
        speed_of_light_mps=SPEED_OF_LIGHT_MPS,
        noise=NoiseSigmas(doppler_hz=1.0, toa_s=3.0 / SPEED_OF_LIGHT_MPS, rss_db=4.0),
        rss_model=RssModel(
            reference_power_dbm=-20.0, reference_distance_m=1.0, path_loss_exponent=2.5
        ),
        description="kilometres from the origin, two headings, 433.92 MHz, c*sigma_tau = 3 m",
    )


def _climb_scenario(n_frames: int = 2) -> Scenario:
    velocities = np.array([[6.0, 8.0, 1.5], [-8.0, 6.0, -1.0]])[:n_frames]
    return Scenario(
        name="climb" if n_frames > 1 else "climb-straight",
        emitter_m=[-60.0, 80.0],
        emitter_height_m=25.0,
        flight=FlightPlan(
            start_position_m=[0.0, 0.0, 40.0],
            frame_velocities_mps=velocities,
            samples_per_frame=10,
            sample_interval_s=0.5,
        ),
        carrier_hz=2.4e9,
        speed_of_light_mps=SPEED_OF_LIGHT_MPS,
        noise=NoiseSigmas(doppler_hz=1.0, toa_s=1.0 / SPEED_OF_LIGHT_MPS, rss_db=4.0),
        rss_model=RssModel(
            reference_power_dbm=-10.0, reference_distance_m=1.0, path_loss_exponent=2.0
        ),
        description="climbing then descending (v_z = 1.5, -1 m/s), emitter 25 m high, 2.4 GHz",
    )


_FIXED_PROBLEMS: dict[str, Callable[[], ReferenceProblem]] = {
    "paper-1m": lambda: ReferenceProblem(
        name="paper-1m",
        scenario=get_scenario("paper-1m"),
        optima_m=[[35.0, 15.0], [35.0, -15.0]],
        source="the paper's emitter (MATH §14) and its mirror image across the track y = 0",
    ),
    "turn": lambda: ReferenceProblem(
        name="turn",
        scenario=get_scenario("turn"),
        optima_m=[[35.0, 15.0]],
        source="the paper's emitter (MATH §14); the second heading removes the mirror",
    ),
    "far-turn": lambda: ReferenceProblem(
        name="far-turn",
        scenario=_far_turn_scenario(),
        optima_m=[[2400.0, -1300.0]],
        source="the emitter; two headings",
    ),
    "climb": lambda: ReferenceProblem(
        name="climb",
        scenario=_climb_scenario(2),
        optima_m=[[-60.0, 80.0]],
        source="the emitter; two headings",
    ),
    "climb-straight": lambda: ReferenceProblem(
        name="climb-straight",
        scenario=_climb_scenario(1),
        optima_m=[[-60.0, 80.0], [93.6, -35.2]],
        source=(
            "the emitter and its mirror image across the track through (0, 0) along "
            "(0.6, 0.8): 2 (s·d) d − s = (93.6, −35.2)"
        ),
    ),
}

_CARRIERS_HZ = (433.92e6, 915e6, 2.4e9, 5.8e9)


def random_problem(seed: int, *, straight: bool) -> ReferenceProblem:
    """A reference problem drawn from ``seed`` (the same seed gives the same problem).

    The emitter lies anywhere within 5 km of the origin at a known height of 0-30 m; the UAV
    flies 20-150 m above it at 5-25 m/s, climbing or descending at up to 2 m/s in half of the
    draws, K = 8-16 samples over a 40-100 m frame, the first frame 25-120 m to the side of
    the emitter; a turn adds one or two frames turned by 60-120°. Carrier 433.92 MHz to
    5.8 GHz; σ_f 0.5-2 Hz, c σ_τ 0.5-5 m, σ_P 4 dB at 0 dB. Draws are redone until the
    emitter is within 150 m of the mean UAV position and 20 m from every frame's track and
    the RMS slant range is at least 65 m.
    """
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0 if straight else 1]))
    name = "random-straight" if straight else "random-turn"
    for _ in range(1000):
        radius, bearing = 5000.0 * math.sqrt(rng.random()), rng.uniform(0.0, 2 * math.pi)
        emitter = radius * np.array([math.cos(bearing), math.sin(bearing)])
        emitter_height = rng.uniform(0.0, 30.0)
        speed = rng.uniform(5.0, 25.0)
        n_samples = int(rng.integers(8, 17))
        frame_length = rng.uniform(40.0, 100.0)
        interval = frame_length / ((n_samples - 1) * speed)
        heading = rng.uniform(0.0, 360.0)
        climb = rng.uniform(-2.0, 2.0) if rng.random() < 0.5 else 0.0
        headings = [heading]
        if not straight:
            for _turn in range(int(rng.integers(1, 3))):
                headings.append(headings[-1] + rng.choice([-1.0, 1.0]) * rng.uniform(60, 120))
        velocities = heading_velocities_mps(speed, headings)
        velocities[:, 2] = climb * rng.choice([-1.0, 1.0], size=len(headings))
        direction = velocities[0, :2] / speed
        normal = np.array([-direction[1], direction[0]])
        along = rng.uniform(-0.5, 0.5) * frame_length
        cross = rng.choice([-1.0, 1.0]) * rng.uniform(25.0, 120.0)
        middle = emitter - along * direction - cross * normal
        start_xy = middle - 0.5 * (n_samples - 1) * interval * velocities[0, :2]
        height = emitter_height + rng.uniform(20.0, 150.0)
        scenario = Scenario(
            name=name,
            emitter_m=emitter,
            emitter_height_m=emitter_height,
            flight=FlightPlan(
                start_position_m=[*start_xy, height],
                frame_velocities_mps=velocities,
                samples_per_frame=n_samples,
                sample_interval_s=interval,
            ),
            carrier_hz=float(rng.choice(_CARRIERS_HZ)),
            speed_of_light_mps=SPEED_OF_LIGHT_MPS,
            noise=NoiseSigmas(
                doppler_hz=rng.uniform(0.5, 2.0),
                toa_s=rng.uniform(0.5, 5.0) / SPEED_OF_LIGHT_MPS,
                rss_db=4.0,
            ),
            rss_model=RssModel(
                reference_power_dbm=rng.uniform(-40.0, 0.0),
                reference_distance_m=1.0,
                path_loss_exponent=rng.uniform(2.0, 3.5),
            ),
            description=f"drawn from check seed {seed}",
        )
        if _well_posed(scenario):
            data = noise_free(scenario)
            line = straight_track_line(data.position_m, data.velocity_mps)
            optima = [emitter] if line is None else [emitter, mirror_across_line(emitter, *line)]
            return ReferenceProblem(
                name=name,
                scenario=scenario,
                optima_m=np.array(optima),
                source=(
                    "the emitter drawn"
                    + ("" if line is None else " and its mirror image")
                    + f" from check seed {seed}"
                ),
                seed=int(seed),
            )
    raise RuntimeError(f"random_problem: no well-posed geometry drawn from seed {seed}")


def _well_posed(scenario: Scenario) -> bool:
    """Emitter within 150 m of the mean UAV position, 20 m off every frame's track, the UAV
    10 m above it, and an RMS slant range of at least 65 m."""
    data = noise_free(scenario)
    emitter = np.asarray(scenario.emitter_m)
    if np.linalg.norm(data.position_m[:, :2].mean(axis=0) - emitter) > 150.0:
        return False
    if np.min(data.position_m[:, 2]) < scenario.emitter_height_m + 10.0:
        return False
    if np.sqrt(np.mean(data.range_m**2)) < 65.0:
        return False
    for frame in data.iter_frames():
        line = straight_track_line(frame.position_m, frame.velocity_mps)
        if line is not None:
            offset = emitter - line[0]
            if abs(line[1][0] * offset[1] - line[1][1] * offset[0]) < 20.0:
                return False
    return True


def reference_problem(name: str, *, seed: int | None = None) -> ReferenceProblem:
    """The named reference problem; a random one is drawn from ``seed`` (or :func:`check_seed`)."""
    if name in _FIXED_PROBLEMS:
        return _FIXED_PROBLEMS[name]()
    if name in RANDOM_PROBLEMS:
        chosen = check_seed() if seed is None else seed
        return random_problem(chosen, straight=name == "random-straight")
    known = ", ".join(REFERENCE_PROBLEMS + RANDOM_PROBLEMS)
    raise ValueError(f"problem: unknown reference problem {name!r}; known: {known}")


def reference_problems(*, seed: int | None = None) -> tuple[ReferenceProblem, ...]:
    """Every reference problem: the fixed ones, then the random ones of ``seed``."""
    return tuple(reference_problem(n, seed=seed) for n in REFERENCE_PROBLEMS + RANDOM_PROBLEMS)


def reference_data(
    scenario: str = "paper-1m", *, noisy: bool = False, frames: int | None = None
) -> tuple[MeasurementSet, np.ndarray]:
    """Fresh reference measurements (truth removed) and the true emitter position (2,).

    Parameters
    ----------
    scenario : str
        A reference problem (:data:`REFERENCE_PROBLEMS`, :data:`RANDOM_PROBLEMS`) or a name of
        :data:`scenarios.catalog.CATALOG`.
    noisy : bool
        False: the exact measurements labelled with the σ's of :data:`NOISE_FREE_SNR_DB`.
        True: one trial at :data:`NOISY_SNR_DB` drawn from :data:`DATA_SEED`.
    frames : int or None
        Frames flown (None: the scenario's own).
    """
    if scenario in _FIXED_PROBLEMS or scenario in RANDOM_PROBLEMS:
        built = reference_problem(scenario).scenario
    elif scenario in CATALOG:
        built = get_scenario(scenario)
    else:
        known = ", ".join(REFERENCE_PROBLEMS + RANDOM_PROBLEMS + tuple(CATALOG))
        raise ValueError(f"scenario: unknown name {scenario!r}; known: {known}")
    if frames is not None:
        built = built.replace(flight=built.flight.with_n_frames(frames))
    if noisy:
        data = simulate(built, snr_db=NOISY_SNR_DB, seed=DATA_SEED)
    else:
        data = noise_free(built, snr_db=NOISE_FREE_SNR_DB)
    return data.without_truth(), np.array(built.emitter_m, dtype=float)


def _noisy(scenario: str = "paper-1m", frames: int | None = None) -> MeasurementSet:
    return reference_data(scenario, noisy=True, frames=frames)[0]


def _rng() -> np.random.Generator:
    return np.random.default_rng(RNG_SEED)


def degenerate_data() -> dict[str, MeasurementSet]:
    """Valid but hopeless measurement sets: what a failure path must handle as data.

    ``hovering``: every sample at one point with zero velocity (no Doppler, no baseline);
    ``short-ranges``: every ToA range (1 m) shorter than the UAV's 50 m height;
    ``one-sample``: a single sample.
    """
    data = _noisy()
    n = data.n_samples
    return {
        "hovering": replace(
            data,
            position_m=np.tile(data.position_m[0], (n, 1)),
            velocity_mps=np.zeros((n, 3)),
            doppler_hz=np.zeros(n),
        ),
        "short-ranges": replace(data, toa_s=np.full(n, 1.0 / data.speed_of_light_mps)),
        "one-sample": data.take(np.arange(n) == 0),
    }


# --------------------------------------------------------------------------------------------
# the forward model at a candidate (MATH §1, §8)
# --------------------------------------------------------------------------------------------


def _whitened_model(
    data: MeasurementSet, point_m: FloatArray, modalities: Iterable[str]
) -> tuple[FloatArray, FloatArray]:
    """Whitened residuals ``(h(s) − y)/σ`` (n,) and Jacobian rows ``∇h/σ`` (n, 2) at ``point_m``
    over ``modalities`` (those absent from ``data`` are skipped)."""
    point = np.asarray(point_m, dtype=float)
    height = data.emitter_height_m
    residuals, rows = [], []
    for modality in MODALITIES:
        if modality not in modalities or modality not in data.modalities:
            continue
        if modality == "doppler":
            predicted = model.doppler_hz(
                data.position_m, data.velocity_mps, point, data.gamma_per_m, height
            )
            gradient = model.doppler_jacobian(
                data.position_m, data.velocity_mps, point, data.gamma_per_m, height
            )
            measured, sigma = data.doppler_hz, data.noise.doppler_hz
        elif modality == "toa":
            predicted = model.toa_s(data.position_m, point, data.speed_of_light_mps, height)
            gradient = model.toa_jacobian(data.position_m, point, data.speed_of_light_mps, height)
            measured, sigma = data.toa_s, data.noise.toa_s
        else:
            assert data.rss_model is not None  # MeasurementSet requires it with RSS
            predicted = model.rss_dbm(data.position_m, point, data.rss_model, height)
            gradient = model.rss_jacobian(data.position_m, point, data.rss_model, height)
            measured, sigma = data.rss_dbm, data.noise.rss_db
        assert measured is not None and sigma is not None
        residuals.append((predicted - measured) / sigma)
        rows.append(gradient / sigma)
    if not rows:
        return np.zeros(0), np.zeros((0, 2))
    return np.concatenate(residuals), np.concatenate(rows)


def data_misfit(
    data: MeasurementSet, point_m: FloatArray, modalities: Iterable[str]
) -> tuple[float, float, float]:
    """How well ``point_m`` reproduces ``data`` (MATH §1), whitened by the data's σ's.

    Returns ``(rms, step_m, unexplained)``: the RMS whitened residual (σ) at the point, the
    length of the Gauss-Newton step from it towards the data (how far the data put the
    emitter from it, to first order), and the RMS residual that step leaves (σ).
    """
    modalities = tuple(modalities)
    residual, rows = _whitened_model(data, point_m, modalities)
    if len(residual) == 0:
        return math.nan, math.nan, math.nan
    step = np.linalg.lstsq(rows, -residual, rcond=None)[0]
    left = residual + rows @ step
    return (
        float(np.sqrt(np.mean(residual**2))),
        float(np.linalg.norm(step)),
        float(np.sqrt(np.mean(left**2))),
    )


def crlb_rmse_m(data: MeasurementSet, emitter_m: FloatArray, modalities: Iterable[str]) -> float:
    """``√trace(J⁻¹)`` (MATH §8) of ``data``'s samples and σ's over ``modalities``; inf if
    ``J`` is singular. (The same bound as :mod:`comparison.crlb`, which estimators may not
    import.)"""
    _, rows = _whitened_model(data, emitter_m, tuple(modalities))
    information = rows.T @ rows
    a, b, d = information[0, 0], information[0, 1], information[1, 1]
    determinant = a * d - b * b
    if not determinant > 1e-12 * abs(a * d):
        return math.inf
    return float(math.sqrt((a + d) / determinant))


# --------------------------------------------------------------------------------------------
# moved and rescaled geometries
# --------------------------------------------------------------------------------------------


def moved(data: MeasurementSet, matrix: FloatArray, offset_m: FloatArray) -> MeasurementSet:
    """The data of the geometry moved by ``x ↦ matrix x + offset_m`` in the horizontal plane.

    ``matrix`` is orthogonal (a rotation or a reflection): positions and velocities move, and
    every noise-free Doppler, ToA and RSS value is unchanged (they depend on distances and
    on ``vᵀu`` only), so the measured values are kept as they are.
    """
    matrix = np.asarray(matrix, dtype=float)
    position = np.array(data.position_m)
    velocity = np.array(data.velocity_mps)
    position[:, :2] = position[:, :2] @ matrix.T + np.asarray(offset_m, dtype=float)
    velocity[:, :2] = velocity[:, :2] @ matrix.T
    return replace(data, position_m=position, velocity_mps=velocity, truth_emitter_m=None)


def in_kilometres(data: MeasurementSet) -> MeasurementSet:
    """The same measurements in km: positions, velocities, c, the emitter height and the RSS
    reference distance divided by 1000; τ, f, P and every σ unchanged."""
    rss_model = data.rss_model
    if rss_model is not None:
        rss_model = replace(rss_model, reference_distance_m=rss_model.reference_distance_m / 1e3)
    return replace(
        data,
        position_m=data.position_m / 1000.0,
        velocity_mps=data.velocity_mps / 1000.0,
        speed_of_light_mps=data.speed_of_light_mps / 1000.0,
        emitter_height_m=data.emitter_height_m / 1000.0,
        rss_model=rss_model,
        truth_emitter_m=None,
    )


def rigid_motions(seed: int) -> list[tuple[str, FloatArray, FloatArray]]:
    """``(description, matrix, offset_m)`` of a translation, a rotation and a reflection drawn
    from ``seed``: a shift by 1-5 km, a turn by 20-340° about a point within 3 km of the
    origin, a reflection across a line through such a point."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 2]))

    def direction(angle: float) -> FloatArray:
        return np.array([math.cos(angle), math.sin(angle)])

    shift = rng.uniform(1000.0, 5000.0) * direction(rng.uniform(0.0, 2 * math.pi))
    angle = math.radians(rng.uniform(20.0, 340.0))
    centre = rng.uniform(-3000.0, 3000.0, size=2)
    rotation = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    tilt = rng.uniform(0.0, math.pi)
    through = rng.uniform(-3000.0, 3000.0, size=2)
    reflection = np.array(
        [[math.cos(2 * tilt), math.sin(2 * tilt)], [math.sin(2 * tilt), -math.cos(2 * tilt)]]
    )
    return [
        (f"translated by ({shift[0]:.1f}, {shift[1]:.1f}) m", np.eye(2), shift),
        (
            f"rotated by {math.degrees(angle):.1f}° about ({centre[0]:.1f}, {centre[1]:.1f}) m",
            rotation,
            centre - rotation @ centre,
        ),
        (
            f"reflected across the line through ({through[0]:.1f}, {through[1]:.1f}) m at "
            f"{math.degrees(tilt):.1f}° from east",
            reflection,
            through - reflection @ through,
        ),
    ]


# --------------------------------------------------------------------------------------------
# small helpers
# --------------------------------------------------------------------------------------------


def _name_of(estimator: Any) -> str:
    return str(getattr(estimator, "name", type(estimator).__name__))


def _fail(message: str) -> None:
    raise AssertionError(" ".join(message.split()))


def _run(
    estimator: Any,
    data: MeasurementSet,
    what: str,
    *,
    rng: np.random.Generator | None = None,
) -> Any:
    """``estimator.estimate(data, rng=rng)``; an exception becomes a failure naming ``what``."""
    try:
        return estimator.estimate(data, rng=rng)
    except Exception as error:
        raise AssertionError(
            f"estimate raised {type(error).__name__} on {what}: {error}; valid data must give an "
            "Estimate (a failure to estimate is Estimate.failed(...), not an exception)"
        ) from error


def _succeeded(estimate: Any, what: str) -> None:
    if not isinstance(estimate, Estimate):
        _fail(
            f"estimate returned {type(estimate).__name__} on {what}, not an "
            "estimators.base.Estimate; build the result with Estimate(...) or finalize_estimate"
        )
    if not estimate.success:
        _fail(
            f"estimate failed on {what} (message: {estimate.message!r}); these data determine "
            "the emitter, so it should succeed there: return Estimate.failed only when the data "
            "cannot give an answer"
        )


def constructor_parameters(estimator: Any) -> list[inspect.Parameter]:
    """The parameters of ``type(estimator)``'s constructor, ``self`` excluded."""
    return list(inspect.signature(type(estimator)).parameters.values())


def params_of(estimator: Any) -> dict[str, Any]:
    """``{parameter: stored value}`` for every constructor parameter stored under its name."""
    return {
        p.name: getattr(estimator, p.name)
        for p in constructor_parameters(estimator)
        if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD) and hasattr(estimator, p.name)
    }


def _capabilities(estimator: Any) -> Capabilities:
    """``capabilities_of(estimator)``; a broken declaration becomes a failure saying so."""
    try:
        return capabilities_of(estimator)
    except Exception as error:
        raise AssertionError(
            f"capabilities() failed ({type(error).__name__}: {error}); return an "
            "estimators.base.Capabilities(modalities=frozenset({...}), ...)"
        ) from error


def _honoured_tolerance_m(capabilities: Capabilities) -> float:
    """The declared tolerance if it is the default or tighter, or looser with a reason."""
    declared = float(capabilities.noise_free_tolerance_m)
    if declared > EXACT_TOLERANCE_M and not capabilities.tolerance_reason.strip():
        return EXACT_TOLERANCE_M
    return declared


def tolerance_cap_m(problem: ReferenceProblem) -> float:
    """The most a declared tolerance counts on ``problem``: :data:`MAX_NOISE_FREE_TOLERANCE`
    times its RMS slant range."""
    return MAX_NOISE_FREE_TOLERANCE * problem.rms_range_m()


def problem_tolerance_m(capabilities: Capabilities, problem: ReferenceProblem) -> float:
    """The noise-free tolerance on ``problem``: the default (1e-6 m, or 1e-9 of the extent),
    loosened by an honoured declaration up to the cap."""
    default = max(EXACT_TOLERANCE_M, EXACT_RTOL * problem.extent_m())
    return max(default, min(_honoured_tolerance_m(capabilities), tolerance_cap_m(problem)))


def _tolerance_text(capabilities: Capabilities, problem: ReferenceProblem) -> str:
    tolerance = problem_tolerance_m(capabilities, problem)
    declared = float(capabilities.noise_free_tolerance_m)
    if declared > EXACT_TOLERANCE_M and not capabilities.tolerance_reason.strip():
        return f"{tolerance:.3g} m: the declared {declared:.3g} m needs a tolerance_reason"
    if declared > tolerance_cap_m(problem):
        return (
            f"{tolerance:.3g} m: the declared {declared:.3g} m capped at "
            f"{MAX_NOISE_FREE_TOLERANCE:g} of the RMS range {problem.rms_range_m():.1f} m"
        )
    if declared > EXACT_TOLERANCE_M and capabilities.tolerance_reason.strip():
        return f"{tolerance:.3g} m, as declared ({capabilities.tolerance_reason.strip()})"
    return f"{tolerance:.3g} m"


@functools.cache
def _smallest_cap_m() -> float:
    return min(tolerance_cap_m(_FIXED_PROBLEMS[name]()) for name in REFERENCE_PROBLEMS)


def noise_free_tolerance_m(estimator: Any, problem: ReferenceProblem | None = None) -> float:
    """The tolerance the checks apply to ``estimator``'s noise-free candidates on ``problem``
    (None: on the problem with the smallest cap), from its declared capabilities only."""
    try:
        capabilities = capabilities_of(estimator)
    except Exception:
        return EXACT_TOLERANCE_M
    if problem is None:
        return max(EXACT_TOLERANCE_M, min(_honoured_tolerance_m(capabilities), _smallest_cap_m()))
    return problem_tolerance_m(capabilities, problem)


def _agreement_m(estimator: Any) -> float:
    return max(AGREEMENT_TOLERANCE_M, noise_free_tolerance_m(estimator))


def _same(a: Any, b: Any) -> bool:
    """Deep equality for parameters and states: arrays by value, dtype and shape; NaN == NaN."""
    if a is b:
        return True
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        if not (isinstance(a, np.ndarray) and isinstance(b, np.ndarray)):
            return False
        if a.shape != b.shape or a.dtype != b.dtype:
            return False
        return bool(np.array_equal(a, b, equal_nan=a.dtype.kind in "fc"))
    if type(a) is not type(b):
        return False
    if isinstance(a, Mapping):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if is_dataclass(a):
        return all(_same(getattr(a, f.name), getattr(b, f.name)) for f in fields(a))
    if isinstance(a, list | tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and math.isnan(a) and math.isnan(b):
        return True
    try:
        return bool(a == b)
    except Exception:
        return False


def _object_state(obj: Any) -> dict[str, Any]:
    """Every instance attribute (``__dict__`` and ``__slots__``), deep-copied."""
    state = dict(getattr(obj, "__dict__", {}))
    for klass in type(obj).__mro__:
        slots = klass.__dict__.get("__slots__", ())
        for slot in (slots,) if isinstance(slots, str) else slots:
            if slot not in ("__dict__", "__weakref__") and hasattr(obj, slot):
                state[slot] = getattr(obj, slot)
    return copy.deepcopy(state)


def _estimate_differences(a: Estimate, b: Estimate, *, atol_m: float | None) -> list[str]:
    """How two estimates differ: bit for bit (``atol_m=None``) or within ``atol_m``.

    With a tolerance, candidates compare as sets and messages and diagnostics are ignored;
    without, everything but timing diagnostics must be identical.
    """
    out = []
    for field in ("estimator", "success", "ambiguous"):
        if getattr(a, field) != getattr(b, field):
            out.append(f"{field} {getattr(a, field)!r} vs {getattr(b, field)!r}")
    pa, pb = np.asarray(a.position_m, dtype=float), np.asarray(b.position_m, dtype=float)
    ca = np.asarray(a.candidates_m, dtype=float).reshape(-1, 2)
    cb = np.asarray(b.candidates_m, dtype=float).reshape(-1, 2)
    if atol_m is None:
        if not _same(pa, pb):
            out.append(f"position_m {pa.tolist()} vs {pb.tolist()}")
        if not _same(ca, cb):
            out.append(f"candidates_m {ca.tolist()} vs {cb.tolist()}")
        ka, kb = a.covariance_m2, b.covariance_m2
        if (ka is None) != (kb is None) or (ka is not None and not _same(ka, kb)):
            out.append("covariance_m2 differs")
        if a.message != b.message:
            out.append(f"message {a.message!r} vs {b.message!r}")
        da = {k: v for k, v in dict(a.diagnostics).items() if not _is_timing(k)}
        db = {k: v for k, v in dict(b.diagnostics).items() if not _is_timing(k)}
        keys = sorted(k for k in da.keys() | db.keys() if not _same(da.get(k), db.get(k)))
        if keys:
            out.append(f"diagnostics {keys} differ")
        return out
    if pa.shape != pb.shape or not np.allclose(pa, pb, rtol=0.0, atol=atol_m, equal_nan=True):
        out.append(f"position_m {pa.tolist()} vs {pb.tolist()} (tolerance {atol_m:g} m)")
    if ca.shape != cb.shape or not np.allclose(
        _sorted_rows(ca), _sorted_rows(cb), rtol=0.0, atol=atol_m
    ):
        out.append(f"candidates_m {ca.tolist()} vs {cb.tolist()} (tolerance {atol_m:g} m)")
    return out


def _is_timing(key: Any) -> bool:
    """A diagnostics key naming a time in seconds (``solve_time_s``): exempt from equality."""
    return isinstance(key, str) and "time" in key and key.endswith("_s")


def _sorted_rows(points: np.ndarray) -> np.ndarray:
    return points[np.lexsort((points[:, 0], points[:, 1]))] if len(points) else points


def _is_json_scalar(value: Any) -> bool:
    return value is None or isinstance(value, str | bool | int | float | np.bool_ | np.number)


def result_problems(estimate: Any, estimator: Any) -> list[str]:
    """Everything wrong with one result's types, shapes and consistency (empty: conforms)."""
    if not isinstance(estimate, Estimate):
        return [_not_an_estimate(estimate)]
    problems = []
    name = getattr(estimator, "name", None)
    if estimate.estimator != name:
        problems.append(
            f"estimator is {estimate.estimator!r} but the class name is {name!r}; "
            "pass self.name to Estimate/finalize_estimate"
        )
    position = estimate.position_m
    if not isinstance(position, np.ndarray) or position.shape != (2,):
        problems.append(
            f"position_m has shape {np.shape(position)}; expected (2,): (x_s, y_s) in metres, "
            "the emitter height is known (MATH §0)"
        )
    candidates = estimate.candidates_m
    if not isinstance(candidates, np.ndarray) or candidates.ndim != 2 or candidates.shape[1] != 2:
        problems.append(f"candidates_m has shape {np.shape(candidates)}; expected (n, 2)")
    if type(estimate.ambiguous) is not bool:
        problems.append(f"ambiguous is {type(estimate.ambiguous).__name__}; expected bool")
    problems += _covariance_problems(estimate.covariance_m2)
    problems += _diagnostics_problems(estimate.diagnostics)
    problems += failure_problems(estimate)
    if problems or not estimate.success:
        return problems
    if len(candidates) == 0:
        problems.append("candidates_m is empty on a success; it must hold position_m (MATH §7)")
    else:
        scale = 1e-9 * max(1.0, float(np.max(np.abs(position))))
        if np.min(np.linalg.norm(candidates - position, axis=1)) > scale:
            problems.append(
                f"position_m {position.tolist()} is not among candidates_m "
                f"{candidates.tolist()}; the returned position is one of the candidates"
            )
    if len(candidates) > 1 and not estimate.ambiguous:
        problems.append(
            f"{len(candidates)} equal-cost candidates but ambiguous is False; several "
            "candidates mean the data cannot choose (MATH §7)"
        )
    return problems


def failure_problems(estimate: Any) -> list[str]:
    """What breaks "a failed estimate is data": ``success`` a bool, ``message`` a str, a NaN
    position and a message when it failed, a finite position when it succeeded."""
    if not isinstance(estimate, Estimate):
        return [_not_an_estimate(estimate)]
    if type(estimate.success) is not bool:
        return [f"success is {type(estimate.success).__name__}; expected bool"]
    if not isinstance(estimate.message, str):
        return [f"message is {type(estimate.message).__name__}; expected str"]
    position = np.asarray(estimate.position_m, dtype=float)
    if not estimate.success:
        problems = []
        if not np.all(np.isnan(position)):
            problems.append(
                f"success is False but position_m is {position.tolist()}; a failed estimate "
                "has a NaN position (use Estimate.failed)"
            )
        if not estimate.message.strip():
            problems.append("success is False with an empty message; say why it failed")
        return problems
    if not np.all(np.isfinite(position)):
        return [
            f"success is True but position_m is {position.tolist()}; return "
            "Estimate.failed(name, reason) when there is no finite answer"
        ]
    return []


def _not_an_estimate(result: Any) -> str:
    return (
        f"returned {type(result).__name__}, not an estimators.base.Estimate; build the "
        "result with Estimate(...), Estimate.failed(...) or finalize_estimate(...)"
    )


def _covariance_problems(covariance: Any) -> list[str]:
    if covariance is None:
        return []
    matrix = np.asarray(covariance)
    if matrix.shape != (2, 2) or matrix.dtype.kind != "f":
        return [f"covariance_m2 has shape {matrix.shape}; expected a (2, 2) float array or None"]
    if not np.all(np.isfinite(matrix)):
        return ["covariance_m2 has non-finite entries; report None when there is no covariance"]
    scale = float(np.max(np.abs(matrix))) or 1.0
    if abs(matrix[0, 1] - matrix[1, 0]) > 1e-9 * scale:
        return ["covariance_m2 is not symmetric; symmetrise it, 0.5 * (P + P.T)"]
    if np.min(np.linalg.eigvalsh(matrix)) < -1e-9 * scale:
        return [
            f"covariance_m2 is not positive semi-definite (eigenvalues "
            f"{np.linalg.eigvalsh(matrix).tolist()}); report None when it is not a covariance"
        ]
    return []


def _diagnostics_problems(diagnostics: Any) -> list[str]:
    if not isinstance(diagnostics, Mapping):
        return [f"diagnostics is {type(diagnostics).__name__}; expected a mapping"]
    problems = []
    for key, value in diagnostics.items():
        if not isinstance(key, str):
            problems.append(f"diagnostics key {key!r} is not a string")
        elif not (
            _is_json_scalar(value)
            or (isinstance(value, list | tuple) and all(_is_json_scalar(v) for v in value))
        ):
            problems.append(
                f"diagnostics[{key!r}] is {type(value).__name__}; diagnostics hold JSON-able "
                "scalars (str, bool, int, float, None) or flat lists of them"
            )
    return problems


# --------------------------------------------------------------------------------------------
# the checks: the constructor and the class
# --------------------------------------------------------------------------------------------


def check_constructor_stores_params(estimator: Any) -> None:
    """The constructor only stores its keyword parameters, unchanged, under their own names.

    Introspects the signature (as scikit-learn's ``get_params`` does): no ``*args`` or
    ``**kwargs``; every parameter has a default (so ``make_estimator(name)`` works); building
    with the defaults stores each default itself; rebuilding with the stored values stores
    those very objects; and no other attribute is set.
    """
    cls = type(estimator)
    parameters = constructor_parameters(estimator)
    for p in parameters:
        if p.kind is p.VAR_POSITIONAL:
            _fail(
                f"{cls.__name__}.__init__ takes *{p.name}; list every option as a keyword "
                "parameter with a default, so that the options can be introspected"
            )
        if p.kind is p.VAR_KEYWORD:
            _fail(
                f"{cls.__name__}.__init__ takes **{p.name}; list every option as a keyword "
                "parameter with a default, so that the options can be introspected"
            )
        if p.default is p.empty:
            _fail(
                f"parameter {p.name!r} has no default; give every option a default so that "
                "make_estimator(name) builds the estimator without options"
            )
        if not hasattr(estimator, p.name):
            _fail(
                f"parameter {p.name!r} is not stored as the attribute {p.name!r}; store every "
                "constructor parameter unchanged under its own name"
            )
    names = {p.name for p in parameters}
    extra = sorted(set(_object_state(estimator)) - names)
    if extra:
        _fail(
            f"the constructor sets {extra}, which are not parameters; compute derived values "
            "inside estimate (or cache them at module level), the constructor only stores options"
        )
    defaults = cls()
    for p in parameters:
        stored = getattr(defaults, p.name)
        if not (
            stored is p.default or (type(stored) is type(p.default) and _same(stored, p.default))
        ):
            _fail(
                f"parameter {p.name!r}: the default {p.default!r} is stored as {stored!r}; store "
                "parameters unchanged (validate them, convert them inside estimate)"
            )
    params = params_of(estimator)
    rebuilt = cls(**params)
    for key, value in params.items():
        stored = getattr(rebuilt, key)
        if not (stored is value or (type(stored) is type(value) and _same(stored, value))):
            _fail(
                f"parameter {key!r}: {value!r} passed to the constructor is stored as "
                f"{stored!r}; store parameters unchanged (convert them inside estimate)"
            )


def check_repr_shows_params(estimator: Any) -> None:
    """``repr`` shows every parameter as ``name=value`` (a dataclass repr does)."""
    text = repr(estimator)
    missing = [f"{k}={v!r}" for k, v in params_of(estimator).items() if f"{k}={v!r}" not in text]
    if missing:
        _fail(
            f"repr {text!r} does not show {missing}; make the estimator a dataclass or write a "
            "__repr__ listing every parameter as name=value"
        )


def check_class_attributes(estimator: Any) -> None:
    """``name`` (a str) and ``requires`` (a frozenset ⊆ {doppler, toa, rss}) are class attributes.

    A class attribute ``noise_free_tolerance_m`` (the old way to loosen the noise-free
    tolerance) is not read: it must be moved to ``capabilities()``.
    """
    cls = type(estimator)
    parameters = {p.name for p in constructor_parameters(estimator)}
    for attribute in ("name", "requires"):
        if attribute in parameters:
            _fail(
                f"{attribute!r} is a constructor parameter; declare it as a class attribute "
                f"(typing.ClassVar in a dataclass)"
            )
    name = getattr(cls, "name", None)
    if not isinstance(name, str) or not name or re.search(r"[\s:]", name):
        _fail(
            f"name is {name!r}; declare name: ClassVar[str] = 'my-method', a non-empty string "
            "without spaces or ':' (':' marks module:Class paths)"
        )
    requires = getattr(cls, "requires", None)
    if not isinstance(requires, frozenset) or not requires <= set(MODALITIES):
        _fail(
            f"requires is {requires!r}; declare requires: ClassVar[frozenset[str]] = "
            f"frozenset({{...}}) with modalities from {set(MODALITIES)}"
        )
    if hasattr(cls, "noise_free_tolerance_m"):
        value = cls.noise_free_tolerance_m
        declared = _capabilities(estimator).noise_free_tolerance_m
        if not (isinstance(value, int | float) and value == declared):
            _fail(
                f"the class attribute noise_free_tolerance_m = {value!r} is not read (the "
                f"declared tolerance is {declared:g} m); declare it in capabilities(): "
                "Capabilities(..., noise_free_tolerance_m=..., tolerance_reason='why'), and "
                "remove the class attribute"
            )


def check_capabilities_declared(estimator: Any) -> None:
    """``capabilities()`` (or the default from the protocol) is consistent with the class.

    It returns a :class:`~estimators.base.Capabilities`; its modalities include ``requires``;
    ``batch`` and ``sequential`` match the methods present; every declared module imports; a
    ``noise_free_tolerance_m`` looser than :data:`EXACT_TOLERANCE_M` has a
    ``tolerance_reason`` and is at most :data:`MAX_NOISE_FREE_TOLERANCE` of the RMS slant
    range of every fixed reference problem.
    """
    capabilities = _capabilities(estimator)
    requires = frozenset(getattr(type(estimator), "requires", frozenset()))
    missing = sorted(requires - capabilities.modalities)
    if missing:
        _fail(
            f"requires {sorted(requires)} but capabilities().modalities is "
            f"{sorted(capabilities.modalities)}, without {missing}; a required modality is "
            "used, so list it in Capabilities.modalities"
        )
    batch = callable(getattr(estimator, "estimate_batch", None))
    if capabilities.batch != batch:
        _fail(
            f"capabilities().batch is {capabilities.batch} but the estimator "
            f"{'has' if batch else 'has no'} estimate_batch; declare batch={batch}"
        )
    sequential = _is_sequential(estimator)
    if capabilities.sequential != sequential:
        _fail(
            f"capabilities().sequential is {capabilities.sequential} but the estimator "
            f"{'has' if sequential else 'lacks'} init/update/estimate_state; declare "
            f"sequential={sequential}"
        )
    for module in capabilities.modules:
        try:
            importlib.import_module(module)
        except Exception as error:
            _fail(
                f"capabilities().modules lists {module!r}, which does not import "
                f"({type(error).__name__}: {error}); install it, or list only the modules "
                "the estimator imports"
            )
    declared = float(capabilities.noise_free_tolerance_m)
    if declared > EXACT_TOLERANCE_M and not capabilities.tolerance_reason.strip():
        _fail(
            f"noise_free_tolerance_m = {declared:g} m is looser than the default "
            f"{EXACT_TOLERANCE_M:g} m without a tolerance_reason; say why the method is not "
            "exact (e.g. 'the refinement stops on a step of 1e-8 of the search radius'), or "
            "drop the declaration; until then the default applies"
        )
    for name in REFERENCE_PROBLEMS:
        problem = _FIXED_PROBLEMS[name]()
        cap = tolerance_cap_m(problem)
        if declared > cap:
            _fail(
                f"noise_free_tolerance_m = {declared:g} m exceeds the cap on {problem.label}: "
                f"{MAX_NOISE_FREE_TOLERANCE:g} of its RMS slant range {problem.rms_range_m():.1f}"
                f" m, i.e. {cap:.3g} m. A noise-free answer that far off is not exact: make "
                "the method converge (a tighter stopping tolerance, a local refinement) and "
                f"declare at most {cap:.3g} m; the checks use the cap meanwhile"
            )


def check_pickle_round_trip(estimator: Any) -> None:
    """The estimator pickles (worker processes need it); the copy has equal parameters and
    gives the same estimate as the original (when the original is itself deterministic)."""
    try:
        copy_ = pickle.loads(pickle.dumps(estimator))
    except Exception as error:
        _fail(
            f"pickling failed ({type(error).__name__}: {error}); keep only picklable options "
            "on the estimator and build solver objects inside estimate"
        )
    if type(copy_) is not type(estimator):
        _fail(f"unpickled a {type(copy_).__name__}, not a {type(estimator).__name__}")
    before, after = params_of(estimator), params_of(copy_)
    changed = sorted(k for k in before if not _same(before[k], after.get(k)))
    if changed:
        _fail(f"the unpickled copy has different parameters {changed}")
    for scenario in ("paper-1m", "turn"):
        what = f"noisy '{scenario}' data"
        original = _run(estimator, _noisy(scenario), what, rng=_rng())
        again = _run(estimator, _noisy(scenario), what, rng=_rng())
        if not isinstance(original, Estimate) or _estimate_differences(
            original, again, atol_m=None
        ):
            continue  # not deterministic: check_estimate_deterministic reports it
        copied = _run(copy_, _noisy(scenario), what, rng=_rng())
        if not isinstance(copied, Estimate):
            _fail(f"the unpickled copy returned {type(copied).__name__} on {what}")
        differences = _estimate_differences(original, copied, atol_m=None)
        if differences:
            _fail(
                f"the unpickled copy gives a different estimate on {what}: "
                f"{'; '.join(differences)}; an estimator's output may depend only on its "
                "parameters, the data and rng"
            )


# --------------------------------------------------------------------------------------------
# the checks: estimate as a pure function
# --------------------------------------------------------------------------------------------


def check_estimate_deterministic(estimator: Any) -> None:
    """The same data give the same estimate, bit for bit: twice without ``rng`` and twice with
    generators of the same seed (compare scikit-learn's ``check_fit_idempotent``)."""
    for scenario in ("paper-1m", "turn"):
        for seeded in (False, True):
            what = f"noisy '{scenario}' data" + (" with rng seeded alike" if seeded else "")
            first = _run(estimator, _noisy(scenario), what, rng=_rng() if seeded else None)
            second = _run(estimator, _noisy(scenario), what, rng=_rng() if seeded else None)
            _succeeded(first, what)
            differences = _estimate_differences(first, second, atol_m=None)
            if differences:
                _fail(
                    f"two calls on {what} differ: {'; '.join(differences)}; draw randomness "
                    "only from the rng argument and keep no state between calls"
                )


def check_estimate_does_not_modify_estimator(estimator: Any) -> None:
    """``estimate`` (and ``estimate_batch``, ``init``/``update``/``estimate_state``) leave
    every attribute of the estimator unchanged (compare scikit-learn's
    ``check_dict_unchanged``)."""
    before = _object_state(estimator)
    for scenario in ("paper-1m", "turn"):
        _run(estimator, _noisy(scenario), f"noisy '{scenario}' data", rng=_rng())
    if callable(getattr(estimator, "estimate_batch", None)):
        estimator.estimate_batch(_batch(), rngs=None)
    if _is_sequential(estimator):
        _stream(estimator, _noisy("turn"), rng=_rng())
    after = _object_state(estimator)
    changed = sorted(
        k for k in before.keys() | after.keys() if not _same(before.get(k), after.get(k))
    )
    if changed:
        _fail(
            f"estimating changed the estimator's attributes {changed}; keep results and caches "
            "out of the estimator (return them in the Estimate or a state value)"
        )


def _field_snapshot(data: Any) -> dict[str, tuple[Any, Any, bool | None]]:
    """``{field: (object, copy, writeable)}`` for every field of a data object."""
    snapshot = {}
    for field in data.__dataclass_fields__:
        value = getattr(data, field)
        writeable = value.flags.writeable if isinstance(value, np.ndarray) else None
        snapshot[field] = (value, copy.deepcopy(value), writeable)
    return snapshot


def _modified_fields(data: Any, snapshot: dict[str, tuple[Any, Any, bool | None]]) -> list[str]:
    changed = []
    for field, (original, saved, writeable) in snapshot.items():
        value = getattr(data, field)
        if value is not original:
            changed.append(f"{field} (replaced)")
        elif not _same(value, saved):
            changed.append(f"{field} (values)")
        elif isinstance(value, np.ndarray) and value.flags.writeable != writeable:
            changed.append(f"{field} (made writeable)")
    return changed


def check_estimate_does_not_modify_inputs(estimator: Any) -> None:
    """``estimate`` changes no field of its :class:`MeasurementSet`: no array written in place,
    no flag flipped, no field replaced (``estimate_batch`` likewise for its batch)."""
    for scenario in ("paper-1m", "turn"):
        data = _noisy(scenario)
        snapshot = _field_snapshot(data)
        _run(estimator, data, f"noisy '{scenario}' data", rng=_rng())
        changed = _modified_fields(data, snapshot)
        if changed:
            _fail(
                f"estimate modified its input on noisy '{scenario}' data: {changed}; work on "
                "copies (np.array(data.toa_s)) or on dataclasses.replace(data, ...)"
            )
    if callable(getattr(estimator, "estimate_batch", None)):
        batch = _batch()
        snapshot = _field_snapshot(batch)
        geometry = _field_snapshot(batch.geometry)
        estimator.estimate_batch(batch, rngs=None)
        changed = _modified_fields(batch, snapshot) + _modified_fields(batch.geometry, geometry)
        if changed:
            _fail(f"estimate_batch modified its input batch: {changed}; work on copies")


def check_estimate_ignores_truth(estimator: Any) -> None:
    """The estimate does not depend on ``truth_emitter_m`` (simulations carry it; estimators
    must not read it): data with a wrong truth give the estimate of data without one."""
    for scenario in ("paper-1m", "turn"):
        what = f"noisy '{scenario}' data"
        blind = _run(estimator, _noisy(scenario), what, rng=_rng())
        again = _run(estimator, _noisy(scenario), what, rng=_rng())
        if not isinstance(blind, Estimate) or _estimate_differences(blind, again, atol_m=None):
            continue  # not deterministic: check_estimate_deterministic reports it
        told = replace(_noisy(scenario), truth_emitter_m=np.array([-1234.5, 678.9]))
        informed = _run(estimator, told, what + " with a truth attached", rng=_rng())
        differences = _estimate_differences(blind, informed, atol_m=None)
        if differences:
            _fail(
                f"attaching a truth to {what} changed the estimate: {'; '.join(differences)}; "
                "never read data.truth_emitter_m inside an estimator"
            )


# --------------------------------------------------------------------------------------------
# the checks: answers on the reference problems (MATH §7, §14)
# --------------------------------------------------------------------------------------------


def _check_exact(estimator: Any, names: Iterable[str]) -> None:
    """Every optimum of the data the estimator uses has a candidate within the tolerance."""
    capabilities = _capabilities(estimator)
    for name in names:
        problem = reference_problem(name)
        what = f"noise-free {problem.label} data"
        estimate = _run(estimator, problem.data(), what)
        _succeeded(estimate, what)
        tolerance = problem_tolerance_m(capabilities, problem)
        candidates = np.asarray(estimate.candidates_m, dtype=float).reshape(-1, 2)
        if len(candidates) == 0:
            _fail(f"no candidate on {what}; candidates_m must hold every equal-cost minimiser")
        for optimum in problem.optima_for(capabilities.frames):
            distance = np.linalg.norm(candidates - optimum, axis=1)
            nearest = int(np.argmin(distance))
            if not distance[nearest] <= tolerance:
                _fail(
                    f"on {what} no candidate is at the optimum {optimum.tolist()} "
                    f"({problem.source}): the nearest, {candidates[nearest].tolist()}, is "
                    f"{distance[nearest]:.3g} m away (tolerance "
                    f"{_tolerance_text(capabilities, problem)}). Noise-free data determine the "
                    "emitter (and its mirror image on one straight frame): compute the answer "
                    "from the data; a method that stops short may declare a looser "
                    "Capabilities.noise_free_tolerance_m with a tolerance_reason, within "
                    f"{MAX_NOISE_FREE_TOLERANCE:g} of the RMS range"
                )


def check_exact_on_straight_frames(estimator: Any) -> None:
    """Noise-free data of one straight frame (``paper-1m``, ``climb-straight``,
    ``random-straight``): the emitter and its mirror image are both candidates, within the
    tolerance."""
    _check_exact(estimator, ("paper-1m", "climb-straight", "random-straight"))


def check_exact_on_turn(estimator: Any) -> None:
    """Noise-free data with two headings (``turn``): a candidate is the emitter (35, 15) m."""
    _check_exact(estimator, ("turn",))


def check_exact_far_from_origin(estimator: Any) -> None:
    """Noise-free ``far-turn`` data, kilometres from the origin: a candidate is the emitter
    (2400, −1300) m, within 1e-6 m (or 1e-9 of the extent)."""
    _check_exact(estimator, ("far-turn",))


def check_exact_with_climb(estimator: Any) -> None:
    """Noise-free ``climb`` data (``v_z ≠ 0``, emitter 25 m high): a candidate is the emitter."""
    _check_exact(estimator, ("climb",))


def check_exact_on_random_geometry(estimator: Any) -> None:
    """Noise-free data of a geometry drawn anew on each run (``random-turn``, from the check
    seed): a candidate is the emitter."""
    _check_exact(estimator, ("random-turn",))


def _distinct(points: FloatArray, tolerance: float) -> FloatArray:
    kept: list[FloatArray] = []
    for point in points:
        if all(np.linalg.norm(point - other) > tolerance for other in kept):
            kept.append(point)
    return np.array(kept).reshape(-1, 2)


def _mirror_closure(
    candidates: FloatArray, data: MeasurementSet, tolerance: float, what: str
) -> None:
    line = straight_track_line(data.position_m, data.velocity_mps)
    assert line is not None  # the reference frames are straight
    for point, mirror in zip(candidates, mirror_across_line(candidates, *line), strict=True):
        if np.min(np.linalg.norm(candidates - mirror, axis=1)) > tolerance:
            _fail(
                f"on {what} the candidate {point.tolist()} comes without its mirror image "
                f"{mirror.tolist()} across the track; report both mirror candidates "
                "(MATH §7; finalize_estimate adds them)"
            )


def check_mirror_pair_reproduces_data(estimator: Any) -> None:
    """One straight frame (``paper-1m``, ``climb-straight``, ``random-straight``): the
    estimate is ``ambiguous``, every candidate reproduces the noise-free data (the
    Gauss-Newton step from it to the data, whitened by the σ's of the modalities it uses, is
    within the tolerance), and there are two distinct candidates, mirror images across the
    track (MATH §7). On noisy data every candidate still comes with its mirror image.

    So a wrong solution fails even when ``finalize_estimate`` adds its mirror image.
    """
    capabilities = _capabilities(estimator)
    for name in ("paper-1m", "climb-straight", "random-straight"):
        problem = reference_problem(name)
        data = problem.data()
        what = f"one straight frame (noise-free {problem.label} data)"
        estimate = _run(estimator, data, what)
        _succeeded(estimate, what)
        if estimate.ambiguous is not True:
            _fail(
                f"ambiguous is {estimate.ambiguous!r} on {what}; one straight frame cannot tell "
                "the side of the track (MATH §7): report ambiguous=True (finalize_estimate does)"
            )
        tolerance = problem_tolerance_m(capabilities, problem)
        candidates = np.asarray(estimate.candidates_m, dtype=float).reshape(-1, 2)
        modalities = sorted(capabilities.modalities & data.modalities)
        fresh = problem.data()  # the estimator may have written to its copy
        for point in candidates:
            rms, step, unexplained = data_misfit(fresh, point, modalities)
            if not (step <= tolerance and unexplained <= MISFIT_LIMIT):
                _fail(
                    f"on {what} the candidate {point.tolist()} does not reproduce the data: "
                    f"its {'+'.join(modalities)} residuals are {rms:.3g} σ RMS and the data put "
                    f"the emitter {step:.3g} m from it (tolerance "
                    f"{_tolerance_text(capabilities, problem)}). Every candidate must fit the "
                    "data: compute the solution from the measurements; adding the mirror image "
                    "of a wrong point (finalize_estimate does) does not make it right"
                )
        distinct = _distinct(candidates, 10.0 * tolerance)
        if len(distinct) < 2:
            _fail(
                f"on {what} the candidates {candidates.tolist()} are one point; the emitter "
                "and its mirror image across the track are two distinct points that fit the "
                "data equally (MATH §7): report both"
            )
        _mirror_closure(candidates, data, tolerance, what)
    data = _noisy("paper-1m")
    what = "one straight frame (noisy 'paper-1m' data)"
    estimate = _run(estimator, data, what)
    _succeeded(estimate, what)
    if estimate.ambiguous is not True:
        _fail(
            f"ambiguous is {estimate.ambiguous!r} on {what}; one straight frame cannot tell "
            "the side of the track (MATH §7): report ambiguous=True (finalize_estimate does)"
        )
    candidates = np.asarray(estimate.candidates_m, dtype=float).reshape(-1, 2)
    _mirror_closure(candidates, data, _agreement_m(estimator), what)


def check_not_ambiguous_with_two_headings(estimator: Any) -> None:
    """Noise-free data with a second heading (``turn``, ``far-turn``, ``climb``,
    ``random-turn``) resolve the side: the estimate is not ``ambiguous`` (MATH §7). Runs for
    estimators that declare ``frames="all"``."""
    for name in ("turn", "far-turn", "climb", "random-turn"):
        problem = reference_problem(name)
        what = f"noise-free {problem.label} data"
        estimate = _run(estimator, problem.data(), what)
        _succeeded(estimate, what)
        if estimate.ambiguous is not False:
            _fail(
                f"ambiguous is {estimate.ambiguous!r} on {what} (candidates "
                f"{np.asarray(estimate.candidates_m).tolist()}); a second heading removes the "
                "mirror ambiguity (MATH §7): use every frame and report one candidate, or "
                "declare the frames used in Capabilities.frames (e.g. frames='last')"
            )


# --------------------------------------------------------------------------------------------
# the checks: invariances
# --------------------------------------------------------------------------------------------


def _matching_gap(expected: FloatArray, got: FloatArray) -> float:
    """Largest distance from a point of either set to the nearest point of the other."""
    if len(expected) != len(got):
        return math.inf
    if len(expected) == 0:
        return 0.0
    distance = np.linalg.norm(expected[:, None, :] - got[None, :, :], axis=-1)
    return float(max(np.max(np.min(distance, axis=1)), np.max(np.min(distance, axis=0))))


def _follows(
    before: Estimate,
    after: Estimate,
    mapped: Callable[[FloatArray], FloatArray],
    tolerance: float,
) -> str:
    """Empty if ``after`` is ``before`` mapped (candidates as sets; the position too when
    there is no tie), else what differs."""
    if before.ambiguous != after.ambiguous:
        return f"ambiguous {before.ambiguous} became {after.ambiguous}"
    expected = mapped(np.asarray(before.candidates_m, dtype=float).reshape(-1, 2))
    got = np.asarray(after.candidates_m, dtype=float).reshape(-1, 2)
    if len(got) != len(expected):
        return (
            f"the candidates are {got.tolist()}, not the {len(expected)} moved ones "
            f"{expected.tolist()}"
        )
    gap = _matching_gap(expected, got)
    if not gap <= tolerance:
        return (
            f"the candidates are {got.tolist()}, the moved ones {expected.tolist()} (gap "
            f"{gap:.3g} m, tolerance {tolerance:.3g} m)"
        )
    if not before.ambiguous and np.shape(before.position_m) == np.shape(after.position_m) == (2,):
        position = mapped(np.asarray(before.position_m, dtype=float)[None, :])[0]
        gap = float(np.linalg.norm(position - after.position_m))
        if not gap <= tolerance:
            return f"position_m is {after.position_m.tolist()}, moved {position.tolist()}"
    return ""


def _answer_differences(a: Any, b: Any, tolerance: float) -> list[str]:
    """How two answers differ: success, ambiguity, candidates as sets, the position when
    there is no tie (empty: the same answer)."""
    if not (isinstance(a, Estimate) and isinstance(b, Estimate)):
        return [_not_an_estimate(b if isinstance(a, Estimate) else a)]
    if a.success != b.success:
        return [f"success {a.success} vs {b.success} ({b.message or a.message!r})"]
    difference = _follows(a, b, lambda points: points, tolerance)
    return [difference] if difference else []


def _invariance_tolerance_m(
    capabilities: Capabilities, problem: ReferenceProblem, data: MeasurementSet
) -> float:
    """The noise-free tolerance of ``problem``, or rounding (:data:`EXACT_RTOL`) at the
    largest coordinate of the moved ``data`` when that is larger."""
    extent = float(np.max(np.abs(data.position_m[:, :2])))
    return max(problem_tolerance_m(capabilities, problem), EXACT_RTOL * extent)


def check_equivariant_under_rigid_motions(estimator: Any) -> None:
    """Translating, rotating or reflecting the geometry (UAV positions and velocities, hence
    the emitter) moves every candidate the same way, within the tolerance, on noisy data of a
    straight frame (``paper-1m``) and of two climbing headings (``climb``). The motions are
    drawn from the check seed; the measured values do not change under them (MATH §1)."""
    capabilities = _capabilities(estimator)
    seed = check_seed()
    for name in ("paper-1m", "climb"):
        problem = reference_problem(name)
        what = f"noisy {problem.label} data"
        before = _run(estimator, problem.data(snr_db=NOISY_SNR_DB), what, rng=_rng())
        _succeeded(before, what)
        for description, matrix, offset in rigid_motions(seed):
            where = f"{what} {description} (check seed {seed}; replay with {CHECK_SEED_ENV}={seed})"
            moved_data = moved(problem.data(snr_db=NOISY_SNR_DB), matrix, offset)
            tolerance = _invariance_tolerance_m(capabilities, problem, moved_data)
            after = _run(estimator, moved_data, where, rng=_rng())
            _succeeded(after, where)
            difference = _follows(
                before, after, lambda points, m=matrix, o=offset: points @ m.T + o, tolerance
            )
            if difference:
                _fail(
                    f"on {where}, {difference}. The estimate must move with the geometry: use "
                    "positions relative to the samples and directions relative to the velocity, "
                    "with no fixed origin, axis or heading (the paper's first-row Doppler line "
                    "of MATH §3 depends on the heading, for one)"
                )


def check_unit_invariant(estimator: Any) -> None:
    """(Only when ``Capabilities.unit_invariant`` is claimed.) The same noisy data in
    kilometres (positions, velocities, c, the emitter height and the RSS reference distance
    divided by 1000; τ, f, P and every σ unchanged) give the same candidates, scaled (MATH §6).
    """
    capabilities = _capabilities(estimator)
    for name in ("paper-1m", "climb"):
        problem = reference_problem(name)
        data = problem.data(snr_db=NOISY_SNR_DB)
        what = f"noisy {problem.label} data"
        metres = _run(estimator, problem.data(snr_db=NOISY_SNR_DB), what, rng=_rng())
        _succeeded(metres, what)
        kilometres = _run(estimator, in_kilometres(data), what + " in kilometres", rng=_rng())
        _succeeded(kilometres, what + " in kilometres")
        scaled = replace(
            kilometres,
            position_m=1000.0 * np.asarray(kilometres.position_m),
            candidates_m=1000.0 * np.asarray(kilometres.candidates_m),
        )
        difference = _follows(
            metres,
            scaled,
            lambda points: points,
            _invariance_tolerance_m(capabilities, problem, data),
        )
        if difference:
            _fail(
                f"on {what} in kilometres (times 1000), {difference}. It claims "
                "unit_invariant=True: weight every residual by its σ (MATH §6) and use no "
                "length or speed constant in metres; or declare unit_invariant=False"
            )


# --------------------------------------------------------------------------------------------
# the checks: the declared capabilities are truthful
# --------------------------------------------------------------------------------------------


def check_unused_modalities_ignored(estimator: Any) -> None:
    """Removing a modality that ``Capabilities.modalities`` does not list (one at a time and
    all together) changes nothing, on noisy data of ``paper-1m`` and ``climb`` that carry all
    three: the comparison scores an estimator against the CRLB of what it declares."""
    capabilities = _capabilities(estimator)
    unused = [m for m in MODALITIES if m not in capabilities.modalities]
    if not unused:
        return
    removals = [(m,) for m in unused] + ([tuple(unused)] if len(unused) > 1 else [])
    for name in ("paper-1m", "climb"):
        problem = reference_problem(name)
        what = f"noisy {problem.label} data"
        full = _run(estimator, problem.data(snr_db=NOISY_SNR_DB), what, rng=_rng())
        _succeeded(full, what)
        for removed in removals:
            fields_ = ", ".join(FIELD_OF_MODALITY[m] for m in removed)
            declared = sorted(capabilities.modalities)
            try:
                reduced = estimator.estimate(
                    problem.data(snr_db=NOISY_SNR_DB).without(*removed), rng=_rng()
                )
            except ValueError as error:
                head = str(error).split(": ", 1)[0]
                if any(FIELD_OF_MODALITY[m] in head for m in removed):
                    _fail(
                        f"without {fields_} the estimate raises ValueError({str(error)!r}), "
                        f"so it reads them, but capabilities().modalities is {declared}; "
                        f"declare {list(removed)} in Capabilities.modalities"
                    )
                raise AssertionError(
                    f"{what} without {fields_}, which it does not declare, raised "
                    f"ValueError({str(error)!r}); a modality outside "
                    f"capabilities().modalities ({declared}) must not matter"
                ) from error
            except Exception as error:
                raise AssertionError(
                    f"{what} without {fields_} raised {type(error).__name__}: {error}; a "
                    f"modality outside capabilities().modalities ({declared}) must not matter"
                ) from error
            differences = _answer_differences(full, reduced, _agreement_m(estimator))
            if differences:
                _fail(
                    f"removing {fields_} from {what} changed the estimate: "
                    f"{'; '.join(differences)}; it uses them, but capabilities().modalities "
                    f"is {declared}: declare {list(removed)} in Capabilities.modalities (or "
                    "stop reading them)"
                )


def check_uses_the_declared_frames(estimator: Any) -> None:
    """``Capabilities.frames`` is truthful, on noisy data of ``turn`` and ``climb``: with
    ``frames="last"`` (or listed frames), dropping the other frames changes nothing; with
    ``frames="all"``, dropping the first frame changes the estimate."""
    capabilities = _capabilities(estimator)
    frames = capabilities.frames
    for name in ("turn", "climb"):
        problem = reference_problem(name)
        data = problem.data(snr_db=NOISY_SNR_DB)
        what = f"noisy {problem.label} data"
        full = _run(estimator, problem.data(snr_db=NOISY_SNR_DB), what, rng=_rng())
        _succeeded(full, what)
        if frames == "all":
            first = int(data.frame[0])
            later = _run(
                estimator, data.take(data.frame != first), what + " without frame 0", rng=_rng()
            )
            if not _answer_differences(full, later, _agreement_m(estimator)):
                _fail(
                    f"dropping frame {first} of {what} did not change the estimate, yet "
                    "capabilities().frames is 'all'; declare the frames it uses "
                    "(Capabilities(frames='last') for the last frame only)"
                )
            continue
        used = select_frames(data, frames)
        if used is None:
            continue
        kept = _run(estimator, used, f"{what}, frames {frames!r} only", rng=_rng())
        differences = _answer_differences(full, kept, _agreement_m(estimator))
        if differences:
            _fail(
                f"keeping only frames {frames!r} (as declared) of {what} changed the estimate: "
                f"{'; '.join(differences)}; it uses other frames too: declare frames='all' (or "
                "the frames it reads)"
            )


# --------------------------------------------------------------------------------------------
# the checks: noisy data (MATH §8)
# --------------------------------------------------------------------------------------------


def check_noisy_error_near_crlb(estimator: Any) -> None:
    """On :data:`CRLB_TRIALS` seeded trials at :data:`CRLB_SNR_DB` of a straight frame
    (``paper-1m``) and of ``far-turn``, the side-resolved RMSE (nearest candidate to the
    emitter) is at most :data:`CRLB_FACTOR` times the CRLB √trace(J⁻¹) of the declared
    modalities and frames (MATH §8). Catches an estimate that ignores the data or collapses
    onto the track when there is noise."""
    capabilities = _capabilities(estimator)
    modalities = sorted(capabilities.modalities)
    for name in ("paper-1m", "far-turn"):
        problem = reference_problem(name)
        batch = problem.trials(snr_db=CRLB_SNR_DB, n_trials=CRLB_TRIALS)
        truth = problem.emitter_m
        errors = []
        for index in range(batch.n_trials):
            what = f"noisy trial {index} of {problem.label} at {CRLB_SNR_DB:g} dB"
            estimate = _run(
                estimator, batch.trial(index), what, rng=np.random.default_rng(RNG_SEED + index)
            )
            _succeeded(estimate, what)
            candidates = np.asarray(estimate.candidates_m, dtype=float).reshape(-1, 2)
            if len(candidates) == 0:
                _fail(f"no candidate on {what}; candidates_m must hold position_m")
            errors.append(float(np.min(np.linalg.norm(candidates - truth, axis=1))))
        used = select_frames(batch.geometry, capabilities.frames)
        bound = crlb_rmse_m(used if used is not None else batch.geometry, truth, modalities)
        rmse = float(np.sqrt(np.mean(np.square(errors))))
        if not rmse <= CRLB_FACTOR * bound:
            _fail(
                f"on {batch.n_trials} noisy trials of {problem.label} at {CRLB_SNR_DB:g} dB the "
                f"side-resolved RMSE (nearest candidate to the emitter {truth.tolist()}) is "
                f"{rmse:.3g} m, {rmse / bound:.3g} times the CRLB √trace(J⁻¹) = {bound:.3g} m of "
                f"the {'+'.join(modalities)} data it declares (frames {capabilities.frames!r}; "
                f"limit {CRLB_FACTOR:g}×); median error {np.median(errors):.3g} m. The answer "
                "must follow the noisy measurements: an estimate that ignores them, or lands on "
                "the track when they are noisy, fails here even if it is exact without noise"
            )


def check_estimate_moves_with_the_emitter(estimator: Any) -> None:
    """The same flight (``turn``) and the same noise draw at :data:`CRLB_SNR_DB`, with the
    emitter at (35, 15) m and then at (−15, 45) m: the answer (the candidate nearest each
    emitter) moves at least half as far as the emitter, in its direction."""
    base = get_scenario("turn")
    emitters = (np.array([35.0, 15.0]), np.array([-15.0, 45.0]))
    found = []
    for emitter in emitters:
        data = simulate(base.replace(emitter_m=emitter), snr_db=CRLB_SNR_DB, seed=DATA_SEED)
        what = f"noisy 'turn' data with the emitter at {emitter.tolist()}"
        estimate = _run(estimator, data.without_truth(), what, rng=_rng())
        _succeeded(estimate, what)
        candidates = np.asarray(estimate.candidates_m, dtype=float).reshape(-1, 2)
        if len(candidates) == 0:
            _fail(f"no candidate on {what}; candidates_m must hold position_m")
        found.append(candidates[np.argmin(np.linalg.norm(candidates - emitter, axis=1))])
    shift = emitters[1] - emitters[0]
    along = float((found[1] - found[0]) @ shift / np.linalg.norm(shift))
    if not along >= 0.5 * float(np.linalg.norm(shift)):
        _fail(
            f"the emitter moved {np.linalg.norm(shift):.1f} m, from {emitters[0].tolist()} to "
            f"{emitters[1].tolist()} (same flight, same noise), but the answer moved "
            f"{along:.3g} m that way, from {found[0].tolist()} to {found[1].tolist()}: the "
            "estimate does not follow the measurements. Compute it from the data"
        )


# --------------------------------------------------------------------------------------------
# the checks: input validation and results
# --------------------------------------------------------------------------------------------


def check_missing_modality_raises(estimator: Any) -> None:
    """Data without a required modality raise ``ValueError`` whose message starts with the
    missing field (``doppler_hz``, ``toa_s``, ``rss_dbm``); ``require_modalities`` does it."""
    for modality in sorted(getattr(type(estimator), "requires", ())):
        field = FIELD_OF_MODALITY[modality]
        data = _noisy().without(modality)
        try:
            estimator.estimate(data)
        except ValueError as error:
            head = str(error).split(": ", 1)[0]
            if field not in head:
                _fail(
                    f"data without {field} raised ValueError({str(error)!r}); start the message "
                    f"with the field, '{field}: ...' (estimators.base.require_modalities)"
                )
            continue
        except Exception as error:
            _fail(
                f"data without {field} raised {type(error).__name__}: {error}; raise ValueError "
                f"naming {field} (call estimators.base.require_modalities first)"
            )
        _fail(
            f"data without {field} gave an estimate although requires contains {modality!r}; "
            "raise ValueError naming the field (estimators.base.require_modalities)"
        )


def check_rejects_wrong_data_type(estimator: Any) -> None:
    """Something that is not a :class:`MeasurementSet` (None, a dict, a path, a batch) raises
    ``TypeError`` or ``ValueError`` at once, not an ``AttributeError`` deep inside."""
    batch = _batch()
    for label, bad in (
        ("None", None),
        ("a dict", {"doppler_hz": [1.0, 2.0]}),
        ("a file name", "measurements.json"),
        ("a MeasurementBatch", batch),
    ):
        try:
            estimator.estimate(bad)
        except (TypeError, ValueError):
            continue
        except Exception as error:
            _fail(
                f"estimate({label}) raised {type(error).__name__}: {error}; check the type "
                "first and raise TypeError('data: expected a MeasurementSet, ...') "
                "(estimators.base.require_modalities does)"
            )
        else:
            _fail(f"estimate({label}) returned a result; it must raise TypeError or ValueError")


def check_rejects_wrong_rng_type(estimator: Any) -> None:
    """An ``rng`` that is neither None nor a ``numpy.random.Generator`` raises ``TypeError``
    or ``ValueError`` (not an ``AttributeError``, and not silently ignored)."""
    try:
        estimator.estimate(_noisy(), rng="not a generator")
    except (TypeError, ValueError):
        return
    except Exception as error:
        _fail(
            f"estimate(data, rng='not a generator') raised {type(error).__name__}: {error}; "
            "raise TypeError naming rng (estimators.base.check_rng)"
        )
    _fail(
        "estimate(data, rng='not a generator') was accepted; raise TypeError naming rng "
        "(estimators.base.check_rng)"
    )


def check_result_types(estimator: Any) -> None:
    """The result is an :class:`Estimate`: ``position_m`` (2,) among ``candidates_m`` (n, 2),
    ``covariance_m2`` (2, 2) symmetric PSD or None, ``success`` bool, ``message`` str,
    ``diagnostics`` a mapping of JSON-able scalars (or flat lists of them), ``estimator``
    equal to ``name``, several candidates only when ``ambiguous``."""
    for scenario in ("paper-1m", "turn"):
        what = f"noisy '{scenario}' data"
        estimate = _run(estimator, _noisy(scenario), what, rng=_rng())
        problems = result_problems(estimate, estimator)
        if not problems and isinstance(estimate, Estimate):
            try:
                json.dumps(estimate.to_dict(), allow_nan=False)
            except (TypeError, ValueError) as error:
                problems.append(f"Estimate.to_dict() is not JSON ({error})")
        if problems:
            _fail(f"on {what}: {'; '.join(problems)}")


def check_failed_estimate_is_data(estimator: Any) -> None:
    """Hopeless but valid data (a hovering UAV, ranges shorter than the height, one sample)
    give an :class:`Estimate` or a ``ValueError`` naming a field; a failed estimate has a NaN
    position, ``success=False`` and a message; a successful one a finite position.
    A sequential estimator's ``estimate_state(init())`` (no frame yet) must fail that way too.
    """
    outcomes: dict[str, Any] = {}
    for label, data in degenerate_data().items():
        try:
            outcomes[label] = estimator.estimate(data)
        except ValueError as error:
            if not _FIELD_PREFIX.match(str(error)):
                _fail(
                    f"{label} data raised ValueError({str(error)!r}); start the message with "
                    "the field at fault and say the fix, e.g. 'velocity_mps: ...'"
                )
            continue
        except Exception as error:
            _fail(
                f"{label} data raised {type(error).__name__}: {error}; return "
                "Estimate.failed(name, reason) or raise ValueError naming the field"
            )
    if _is_sequential(estimator):
        try:
            before_any_frame = estimator.estimate_state(estimator.init())
        except Exception as error:
            _fail(
                f"estimate_state(init()) raised {type(error).__name__}: {error}; return "
                "Estimate.failed(name, 'no frame has been processed yet')"
            )
        if getattr(before_any_frame, "success", None) is not False:
            _fail(
                "estimate_state(init()) does not fail before any frame; return "
                "Estimate.failed(name, 'no frame has been processed yet')"
            )
        outcomes["estimate_state(init())"] = before_any_frame
    for label, estimate in outcomes.items():
        problems = failure_problems(estimate)
        if problems:
            _fail(f"on {label}: {'; '.join(problems)}")


# --------------------------------------------------------------------------------------------
# the checks: optional capabilities
# --------------------------------------------------------------------------------------------


def _batch() -> MeasurementBatch:
    """Four noisy trials of one straight frame (``paper-1m``)."""
    scenario = get_scenario("paper-1m")
    seeds = np.random.SeedSequence(DATA_SEED).spawn(4)
    batch = simulate_trials(scenario, snr_db=NOISY_SNR_DB, seeds=seeds)
    return replace(batch, geometry=batch.geometry.without_truth())


def _is_sequential(estimator: Any) -> bool:
    return all(callable(getattr(estimator, m, None)) for m in ("init", "update", "estimate_state"))


def _stream(estimator: Any, data: MeasurementSet, *, rng: np.random.Generator | None) -> Any:
    state = estimator.init()
    for frame in data.iter_frames():
        state = estimator.update(state, frame)
    return estimator.estimate_state(state, rng=rng)


def check_batch_matches_single(estimator: Any) -> None:
    """``estimate_batch`` returns one estimate per trial, each equal (within the agreement
    tolerance) to ``estimate`` on that trial with the same ``rng``."""
    batch = _batch()
    rngs = [np.random.default_rng(RNG_SEED + i) for i in range(batch.n_trials)]
    results = list(estimator.estimate_batch(batch, rngs=rngs))
    if len(results) != batch.n_trials:
        _fail(f"estimate_batch returned {len(results)} estimates for {batch.n_trials} trials")
    for index, result in enumerate(results):
        problems = result_problems(result, estimator)
        if problems:
            _fail(f"estimate_batch, trial {index}: {'; '.join(problems)}")
        single = _run(
            estimator,
            batch.trial(index),
            f"trial {index}",
            rng=np.random.default_rng(RNG_SEED + index),
        )
        differences = _estimate_differences(result, single, atol_m=_agreement_m(estimator))
        if differences:
            _fail(
                f"estimate_batch differs from estimate on trial {index}: "
                f"{'; '.join(differences)}; a trial's result may not depend on its batch"
            )


def check_streaming_matches_estimate(estimator: Any) -> None:
    """``init``, ``update`` per frame of ``iter_frames`` and ``estimate_state`` give
    ``estimate``'s answer (within the agreement tolerance), with and without a turn."""
    for scenario, frames in (("turn", None), ("paper-1m", 2)):
        data = _noisy(scenario, frames)
        what = f"noisy '{scenario}' data, {data.frames.size} frames"
        whole = _run(estimator, data, what, rng=_rng())
        streamed = _stream(estimator, _noisy(scenario, frames), rng=_rng())
        problems = result_problems(streamed, estimator)
        if problems:
            _fail(f"estimate_state on {what}: {'; '.join(problems)}")
        differences = _estimate_differences(whole, streamed, atol_m=_agreement_m(estimator))
        if differences:
            _fail(
                f"streaming differs from estimate on {what}: {'; '.join(differences)}; "
                "estimate(data) should equal init/update over data.iter_frames()/estimate_state"
            )


def check_sequential_update_is_pure(estimator: Any) -> None:
    """``update(state, frame)`` returns a new state and leaves ``state`` usable: updating one
    state twice gives the same estimate, and an old state still gives its old estimate."""
    frames = list(_noisy("turn").iter_frames())
    first = estimator.update(estimator.init(), frames[0])
    before = estimator.estimate_state(first, rng=_rng())
    second = estimator.update(first, frames[1])
    again = estimator.update(first, frames[1])
    for label, a, b in (
        (
            "the first state after a second update",
            before,
            estimator.estimate_state(first, rng=_rng()),
        ),
        (
            "two updates of the same state",
            estimator.estimate_state(second, rng=_rng()),
            estimator.estimate_state(again, rng=_rng()),
        ),
    ):
        differences = _estimate_differences(a, b, atol_m=_agreement_m(estimator))
        if differences:
            _fail(
                f"{label} changed the estimate: {'; '.join(differences)}; update must return "
                "a new state and never modify the one it is given (an optax-style pure pair)"
            )


# --------------------------------------------------------------------------------------------
# running the checks
# --------------------------------------------------------------------------------------------

CHECKS: tuple[Check, ...] = (
    check_constructor_stores_params,
    check_repr_shows_params,
    check_class_attributes,
    check_capabilities_declared,
    check_pickle_round_trip,
    check_estimate_deterministic,
    check_estimate_does_not_modify_estimator,
    check_estimate_does_not_modify_inputs,
    check_estimate_ignores_truth,
    check_exact_on_straight_frames,
    check_exact_on_turn,
    check_exact_far_from_origin,
    check_exact_with_climb,
    check_exact_on_random_geometry,
    check_mirror_pair_reproduces_data,
    check_not_ambiguous_with_two_headings,
    check_equivariant_under_rigid_motions,
    check_unit_invariant,
    check_unused_modalities_ignored,
    check_uses_the_declared_frames,
    check_noisy_error_near_crlb,
    check_estimate_moves_with_the_emitter,
    check_missing_modality_raises,
    check_rejects_wrong_data_type,
    check_rejects_wrong_rng_type,
    check_result_types,
    check_failed_estimate_is_data,
    check_batch_matches_single,
    check_streaming_matches_estimate,
    check_sequential_update_is_pure,
)
"""Every check, in the order they run."""

CHECK_NAMES = tuple(check.__name__ for check in CHECKS)

_BATCH_CHECKS = frozenset({"check_batch_matches_single"})
_SEQUENTIAL_CHECKS = frozenset(
    {"check_streaming_matches_estimate", "check_sequential_update_is_pure"}
)


def estimator_checks(estimator: Any) -> Iterator[Check]:
    """The checks that apply to ``estimator``: the batch and streaming ones only when it has
    those methods, the unit check only when it claims ``unit_invariant``, the two-headings
    check only when it declares ``frames="all"`` (a broken ``capabilities()`` runs them all
    but the unit check, and ``check_capabilities_declared`` reports it)."""
    if isinstance(estimator, type):
        raise TypeError(
            f"estimator: got the class {estimator.__name__}; pass an instance, e.g. "
            f"{estimator.__name__}()"
        )
    batch = callable(getattr(estimator, "estimate_batch", None))
    sequential = _is_sequential(estimator)
    try:
        capabilities: Capabilities | None = capabilities_of(estimator)
    except Exception:
        capabilities = None
    for check in CHECKS:
        if check.__name__ in _BATCH_CHECKS and not batch:
            continue
        if check.__name__ in _SEQUENTIAL_CHECKS and not sequential:
            continue
        if check is check_unit_invariant and not (capabilities and capabilities.unit_invariant):
            continue
        if (
            check is check_not_ambiguous_with_two_headings
            and capabilities is not None
            and capabilities.frames != "all"
        ):
            continue
        yield check


def _expected(
    estimator: Any,
    expected_failed_checks: Mapping[str, str] | Callable[[Any], Mapping[str, str]] | None,
) -> dict[str, str]:
    if expected_failed_checks is None:
        return {}
    reasons = (
        expected_failed_checks(estimator)
        if callable(expected_failed_checks)
        else expected_failed_checks
    )
    reasons = dict(reasons or {})
    unknown = sorted(set(reasons) - set(CHECK_NAMES))
    if unknown:
        raise ValueError(
            f"expected_failed_checks: unknown checks {unknown}; known: {', '.join(CHECK_NAMES)}"
        )
    return reasons


class EstimatorCheckError(AssertionError):
    """Raised by :func:`check_estimator`; ``failures`` maps each failed check to its message."""

    def __init__(self, estimator: Any, failures: dict[str, str], unexpected: list[str]) -> None:
        self.failures = failures
        self.unexpected_passes = unexpected
        lines = [f"{_estimator_id(estimator)} fails {len(failures)} conformance check(s):"]
        lines += [f"- {name}: {message}" for name, message in failures.items()]
        lines += [
            f"- {name}: expected to fail but passed; remove it from expected_failed_checks"
            for name in unexpected
        ]
        super().__init__("\n".join(lines))


@dataclass(frozen=True, slots=True)
class CheckOutcome:
    """The outcome of one check: ``passed``, or the failure message (and whether expected)."""

    name: str
    passed: bool
    message: str = ""
    expected_reason: str | None = None


def run_checks(
    estimator: Any,
    *,
    expected_failed_checks: Mapping[str, str] | Callable[[Any], Mapping[str, str]] | None = None,
) -> list[CheckOutcome]:
    """Run every applicable check and return the outcomes (never raises for a failure)."""
    reasons = _expected(estimator, expected_failed_checks)
    outcomes = []
    for check in estimator_checks(estimator):
        try:
            check(estimator)
        except Exception as error:
            message = (
                str(error)
                if isinstance(error, AssertionError)
                else (f"{type(error).__name__}: {error}")
            )
            outcomes.append(
                CheckOutcome(check.__name__, False, message, reasons.get(check.__name__))
            )
        else:
            outcomes.append(CheckOutcome(check.__name__, True, "", reasons.get(check.__name__)))
    return outcomes


def check_estimator(
    estimator: Any,
    *,
    expected_failed_checks: Mapping[str, str] | Callable[[Any], Mapping[str, str]] | None = None,
) -> list[CheckOutcome]:
    """Run every applicable check on ``estimator``; raise if any fails unexpectedly.

    Parameters
    ----------
    estimator : object
        An estimator instance (see :class:`estimators.base.Estimator`).
    expected_failed_checks : mapping or callable, optional
        ``{"check_name": "reason"}`` (or a function of the estimator returning one) for the
        checks the estimator fails by design; each must fail.

    Returns
    -------
    list of CheckOutcome
        Every check run, when none failed unexpectedly.

    Raises
    ------
    EstimatorCheckError
        An ``AssertionError`` listing every unexpected failure with what to fix, and every
        expected failure that passed.
    """
    outcomes = run_checks(estimator, expected_failed_checks=expected_failed_checks)
    failures = {o.name: o.message for o in outcomes if not o.passed and o.expected_reason is None}
    unexpected = [o.name for o in outcomes if o.passed and o.expected_reason is not None]
    if failures or unexpected:
        raise EstimatorCheckError(estimator, failures, unexpected)
    return outcomes


def _estimator_id(estimator: Any) -> str:
    """``Class(option=value, ...)`` with the options that differ from their defaults."""
    try:
        changed = []
        for p in constructor_parameters(estimator):
            if p.default is not p.empty and hasattr(estimator, p.name):
                value = getattr(estimator, p.name)
                if not _same(value, p.default):
                    changed.append(f"{p.name}={value!r}")
    except (TypeError, ValueError):
        changed = []
    return f"{type(estimator).__name__}({', '.join(changed)})"


def parametrize_with_checks(
    estimators: Iterable[Any],
    *,
    expected_failed_checks: Mapping[str, str] | Callable[[Any], Mapping[str, str]] | None = None,
) -> Any:
    """A ``pytest.mark.parametrize`` over every (estimator, applicable check) pair.

    Test ids read ``Class(non-default options)-check_name``. Checks listed in
    ``expected_failed_checks`` (a mapping, or a function of the estimator returning one) are
    marked ``xfail(strict=True)`` with the recorded reason: they must fail.

    Examples
    --------
    >>> @parametrize_with_checks([MyEstimator()])          # doctest: +SKIP
    ... def test_conformance(estimator, check):
    ...     check(estimator)
    """
    import pytest

    params = []
    for estimator in estimators:
        reasons = _expected(estimator, expected_failed_checks)
        for check in estimator_checks(estimator):
            marks = []
            if check.__name__ in reasons:
                marks.append(pytest.mark.xfail(strict=True, reason=reasons[check.__name__]))
            params.append(
                pytest.param(
                    estimator, check, id=f"{_estimator_id(estimator)}-{check.__name__}", marks=marks
                )
            )
    return pytest.mark.parametrize("estimator, check", params)


__all__ = [
    "AGREEMENT_TOLERANCE_M",
    "CHECKS",
    "CHECK_NAMES",
    "CHECK_SEED_ENV",
    "CRLB_FACTOR",
    "CRLB_SNR_DB",
    "CRLB_TRIALS",
    "EXACT_RTOL",
    "EXACT_TOLERANCE_M",
    "MAX_NOISE_FREE_TOLERANCE",
    "NOISE_FREE_SNR_DB",
    "RANDOM_PROBLEMS",
    "REFERENCE_PROBLEMS",
    "REFERENCE_SCENARIOS",
    "CheckOutcome",
    "EstimatorCheckError",
    "ReferenceProblem",
    "check_estimator",
    "check_seed",
    "crlb_rmse_m",
    "data_misfit",
    "estimator_checks",
    "in_kilometres",
    "moved",
    "parametrize_with_checks",
    "problem_tolerance_m",
    "random_problem",
    "reference_data",
    "reference_problem",
    "reference_problems",
    "result_problems",
    "run_checks",
    *CHECK_NAMES,
]
