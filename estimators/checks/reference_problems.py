"""The reference problems of the conformance suite, their data and the check seed.

Reference problems (:class:`ReferenceProblem`, like cvxpy's ``sdp_1``) are geometries whose
optimum is known and recorded: on noise-free data the minimisers of every consistent cost are
the emitter, and on one straight frame also its mirror image across the track (MATH §7). The
fixed ones (:data:`REFERENCE_PROBLEMS`):

- ``paper-1m``: the paper's straight frame (MATH §14); optima (35, ±15) m;
- ``turn``: the same emitter, east then north; optimum (35, 15) m;
- ``far-turn``: kilometres from the origin, emitter (2400, −1300) m, 433.92 MHz, two headings;
  optimum (2400, −1300) m;
- ``climb``: climbing and descending frames (``v_z ≠ 0``), emitter (−60, 80) m at a known height
  of 25 m, 2.4 GHz; optimum (−60, 80) m;
- ``climb-straight``: the first, climbing frame of ``climb``; optima (−60, 80) m and its mirror
  (93.6, −35.2) m.

Two more are drawn at random on every run of the suite (``random-straight``, one straight frame,
and ``random-turn``, two or three headings): an emitter anywhere within 5 km of the origin with
a known height, a flight 25-120 m to its side, random speed, heading, climb rate, carrier,
sampling and noise levels (:func:`random_problem`). Their seed, the *check seed*, comes from OS
entropy once per process, or from the environment variable ``EMITTERBENCH_CHECK_SEED``; every
message about a random problem names it, and ``EMITTERBENCH_CHECK_SEED=<seed> pytest ...``
replays the failure (the check seed also draws the translation, rotation and reflection of the
equivariance check). A random emitter lies within 150 m of the mean UAV position (as every fixed
one does) and at least 20 m from every frame's track, and a random problem has an RMS slant
range of at least 65 m (the fixed ones: 60.7 m on ``turn`` to 134 m on ``far-turn``), so that
its tolerance cap is never below the fixed problems'.

Three more have the emitter's height unknown (:data:`HEIGHT_PROBLEMS`, MATH §7, §8), for an
estimator whose ``Capabilities.unknowns`` contains ``"emitter_height_m"``: their optima have
three coordinates ``(x, y, z)``, and the minimisers are not those of the known height:

- ``climb-height``: ``climb`` with the height unknown; optimum (−60, 80, 25) m (the change of
  altitude leaves one minimum);
- ``turn-height``: the emitter 20 m high under the level ``turn`` at 50 m, its height unknown;
  optimum (35, 15, 20) m; its reflection through the flight plane, (35, 15, 80) m, fits the
  data equally but is above the UAV (the mirror rule drops it);
- ``climb-straight-height``: the straight frame of ``climb-straight`` with the height unknown:
  the emitter anywhere on a circle about the track, no optimum (the estimate fails in one
  line).

One more data set is not a reference problem (its optimum is not the emitter): the trap of
``check_leaves_the_track`` (:func:`on_track_start_data`), whose first frame alone puts the
closed form's candidate on the track (MATH §5) while the truth is 15 m off it.

*Noise-free* data are exact measurements labelled with the σ's of :data:`NOISE_FREE_SNR_DB` =
100 dB (MATH §2), the limit of vanishing noise, so that weights and de-biasing factors that
depend on σ are those of noise-free data. *Noisy* data are seeded trials (:data:`DATA_SEED`).
Every call gets freshly built data, so that a check never sees what another call did to them.
"""

from __future__ import annotations

import math
import os
import secrets
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from scenarios.catalog import CATALOG, get_scenario, heading_velocities_mps
from scenarios.geometry import mirror_across_line, straight_track_line
from scenarios.nuisance import HEIGHT_UNKNOWN, position_dimension
from scenarios.simulate import noise_free, simulate, simulate_trials
from scenarios.types import (
    SPEED_OF_LIGHT_MPS,
    FlightPlan,
    MeasurementBatch,
    MeasurementSet,
    NoiseSigmas,
    RssModel,
    Scenario,
)

FloatArray = NDArray[np.float64]

NOISE_FREE_SNR_DB = 100.0
"""The SNR whose σ's label the noise-free reference data (MATH §2): vanishing noise."""

NOISY_SNR_DB = 10.0
"""The SNR of the noisy trials of the behavioural checks (determinism, batch, equivariance)."""

DATA_SEED = 20_240_601
"""Seed of the noisy trials (fixed: the noisy checks are reproducible)."""

RNG_SEED = 7
"""Seed of the tie-breaking generators the checks pass as ``rng``."""

CHECK_SEED_ENV = "EMITTERBENCH_CHECK_SEED"
"""Environment variable that fixes the check seed (random problems, moved geometries)."""

REFERENCE_PROBLEMS = ("paper-1m", "turn", "far-turn", "climb", "climb-straight")
"""The fixed reference problems; :data:`RANDOM_PROBLEMS` are drawn from the check seed."""

HEIGHT_PROBLEMS = ("climb-height", "turn-height", "climb-straight-height")
"""The fixed reference problems with the emitter's height unknown (module text)."""

TURN_HEIGHT_M = 20.0
"""The emitter's height in ``turn-height``, under the UAV's 50 m."""

RANDOM_PROBLEMS = ("random-straight", "random-turn")
"""The reference problems drawn anew on every run (from :func:`check_seed`)."""

REFERENCE_SCENARIOS = ("paper-1m", "turn", "orbit")
"""Named scenarios of :mod:`scenarios.catalog` that :func:`reference_data` also accepts."""

ON_TRACK_START_SNR_DB = -10.0
"""The SNR whose Doppler and ToA σ's label the data of :func:`on_track_start_data`."""

ON_TRACK_START_SHORTFALL_M = 3.0
"""How much shorter than the truth the first frame's ranges of :func:`on_track_start_data` are."""

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


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class ReferenceProblem:
    """A geometry with a known, recorded optimum (cvxpy's ``sdp_1``).

    Attributes
    ----------
    name : str
    scenario : Scenario
        Emitter, flight and constants; it simulates Doppler, ToA and RSS.
    optima_m : (n, 2) or (n, 3)
        Every minimiser on noise-free data from all frames: the emitter, and on one straight
        frame also its mirror image across the track (MATH §7); ``(x, y, z)`` when the
        scenario declares the emitter's height unknown (:attr:`dimension`), none on a straight
        track then (MATH §7).
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
        optima = np.array(self.optima_m, dtype=float).reshape(-1, self.dimension)
        optima.flags.writeable = False
        object.__setattr__(self, "optima_m", optima)

    @property
    def label(self) -> str:
        """The name as messages show it; a random problem's says how to replay it."""
        if self.seed is None:
            return f"'{self.name}'"
        return f"'{self.name}' (check seed {self.seed}; replay with {CHECK_SEED_ENV}={self.seed})"

    @property
    def dimension(self) -> int:
        """The position's coordinates: 3 when the scenario declares the height unknown."""
        return position_dimension(self.scenario.unknowns)

    @property
    def emitter_m(self) -> FloatArray:
        """The emitter ``(x, y)``, or ``(x, y, z)`` with the height unknown."""
        emitter = np.array(self.scenario.emitter_m, dtype=float)
        if self.dimension == 3:
            return np.append(emitter, self.scenario.emitter_height_m)
        return emitter

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
        mirror image across that frame's track (with the height unknown: none, MATH §7); any
        other subset: the emitter.
        """
        if frames == "all":
            return self.optima_m
        used = select_frames(noise_free(self.scenario), frames)
        if used is None:
            return self.optima_m
        line = straight_track_line(used.position_m, used.velocity_mps)
        if line is None:
            return self.emitter_m[None, :]
        if self.dimension == 3:
            return np.empty((0, 3))
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


def _height_unknown(scenario: Scenario, name: str, height_m: float | None = None) -> Scenario:
    """``scenario`` renamed, its emitter's height (``height_m``, or its own) declared unknown."""
    height = scenario.emitter_height_m if height_m is None else height_m
    return scenario.replace(name=name, unknowns=(HEIGHT_UNKNOWN,), emitter_height_m=height)


FIXED_PROBLEMS: dict[str, Callable[[], ReferenceProblem]] = {
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
    "climb-height": lambda: ReferenceProblem(
        name="climb-height",
        scenario=_height_unknown(_climb_scenario(2), "climb-height"),
        optima_m=[[-60.0, 80.0, 25.0]],
        source="the emitter, 25 m high, its height unknown; the change of altitude and the "
        "second heading leave one minimum",
    ),
    "turn-height": lambda: ReferenceProblem(
        name="turn-height",
        scenario=_height_unknown(get_scenario("turn"), "turn-height", TURN_HEIGHT_M),
        optima_m=[[35.0, 15.0, TURN_HEIGHT_M]],
        source=(
            "the emitter 20 m high under the level turn at 50 m, its height unknown; its "
            "reflection (35, 15, 80) m fits equally but is above the UAV (MATH §7)"
        ),
    ),
    "climb-straight-height": lambda: ReferenceProblem(
        name="climb-straight-height",
        scenario=_height_unknown(_climb_scenario(1), "climb-straight-height"),
        optima_m=np.empty((0, 3)),
        source="one straight track with the height unknown: a circle about it (MATH §7)",
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
    if name in FIXED_PROBLEMS:
        return FIXED_PROBLEMS[name]()
    if name in RANDOM_PROBLEMS:
        chosen = check_seed() if seed is None else seed
        return random_problem(chosen, straight=name == "random-straight")
    known = ", ".join(REFERENCE_PROBLEMS + RANDOM_PROBLEMS + HEIGHT_PROBLEMS)
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
    if scenario in FIXED_PROBLEMS or scenario in RANDOM_PROBLEMS:
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


def on_track_start_data() -> tuple[MeasurementSet, MeasurementSet, FloatArray]:
    """The trap of ``check_leaves_the_track``: ``(data, exact, emitter_m)``.

    The paper's emitter (35, 15) m (MATH §14), flown east for two frames and then north for one
    (K = 10 samples of 0.05 s at 10 m/s each). ``exact`` holds the noise-free measurements,
    labelled with the Doppler and ToA σ's of :data:`ON_TRACK_START_SNR_DB` = −10 dB
    (``σ_f = 0.32`` Hz, ``c σ_τ = 3.16`` m) and the RSS σ of :data:`NOISE_FREE_SNR_DB` (RSS is
    exact, and estimators that de-bias it by σ see it so). ``data`` are the same but for the
    first frame's ToA ranges, :data:`ON_TRACK_START_SHORTFALL_M` = 3 m (0.95 σ) short, as noise
    often makes them at low SNR: too short to reach the emitter's cross-track offset, so that
    the least-squares line of that frame misses the paraboloid and the closed form's unique
    minimiser lies on the track (MATH §5, the case beside the hard case), at (33.5, 0) m. The
    second frame continues the track exactly, so the likelihood's minimum leaves the track
    while a point on it stays a stationary point by symmetry (MATH §7); the third, after the
    turn, decides the side. The truth is removed from ``data``.
    """
    base = get_scenario("turn")
    scenario = base.replace(
        name="on-track-start",
        flight=replace(
            base.flight, frame_velocities_mps=heading_velocities_mps(10.0, [0.0, 0.0, 90.0])
        ),
    )
    labelled = noise_free(scenario, snr_db=ON_TRACK_START_SNR_DB)
    noise = replace(labelled.noise, rss_db=scenario.noise.at_snr(NOISE_FREE_SNR_DB).rss_db)
    exact = replace(labelled, noise=noise)
    assert exact.toa_s is not None  # the scenario simulates ToA
    shortfall_s = ON_TRACK_START_SHORTFALL_M / exact.speed_of_light_mps
    toa_s = exact.toa_s - np.where(exact.frame == exact.frame[0], shortfall_s, 0.0)
    data = replace(exact, toa_s=toa_s).without_truth()
    return data, exact.without_truth(), np.array(scenario.emitter_m, dtype=float)


def noisy_reference(scenario: str = "paper-1m", frames: int | None = None) -> MeasurementSet:
    """The reference problem's noisy data of ``scenario`` (:func:`reference_data`)."""
    return reference_data(scenario, noisy=True, frames=frames)[0]


def reference_rng() -> np.random.Generator:
    """The checks' generator, seeded with :data:`RNG_SEED` (a new one per call)."""
    return np.random.default_rng(RNG_SEED)


def degenerate_data() -> dict[str, MeasurementSet]:
    """Valid but hopeless measurement sets: what a failure path must handle as data.

    ``hovering``: every sample at one point with zero velocity (no Doppler, no baseline);
    ``short-ranges``: every ToA range (1 m) shorter than the UAV's 50 m height, within the noise
    of the paper's printed ``c σ_τ = 300 km`` (a shorter range beyond the noise is refused by
    the data types);
    ``one-sample``: a single sample.
    """
    data = noisy_reference()
    n = data.n_samples
    return {
        "hovering": replace(
            data,
            position_m=np.tile(data.position_m[0], (n, 1)),
            velocity_mps=np.zeros((n, 3)),
            doppler_hz=np.zeros(n),
        ),
        "short-ranges": replace(
            data,
            toa_s=np.full(n, 1.0 / data.speed_of_light_mps),
            noise=replace(data.noise, toa_s=1e-3),
        ),
        "one-sample": data.take(np.arange(n) == 0),
    }


def reference_batch() -> MeasurementBatch:
    """Four noisy trials of one straight frame (``paper-1m``)."""
    scenario = get_scenario("paper-1m")
    seeds = np.random.SeedSequence(DATA_SEED).spawn(4)
    batch = simulate_trials(scenario, snr_db=NOISY_SNR_DB, seeds=seeds)
    return replace(batch, geometry=batch.geometry.without_truth())
