"""The Cramér-Rao bounds a run scores against (MATH §8), and the rows of the points table.

Every (scenario, point) of an experiment gets a :class:`PointInfo` in the main process
(:func:`point_infos`): its scenario, SNR, swept settings and, for every modality set needed,
the per-frame statistics of the Fisher information at the truth
(:class:`~scenarios.fisher.InformationStatistics`). An estimator's bound (``crlb_rmse_m``) uses
the modalities and frames it declares (:func:`crlb_key`, from its ``capabilities()``, never
from option names): the information of the union of those frames' samples, with one carrier
offset and one emission time shared by all of them when they are unknown (MATH §15). In a
closed loop every trial flies its own trajectory, so the worker computes the information of
that trial (:func:`information_at_truth`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from comparison.crlb import crlb_m2, crlb_parts_m, rmse_bound_m
from comparison.trial_rows import (
    POINT_CRLB_SETS,
    POINT_HEIGHT_CRLB,
    POINT_KNOWN_CRLB_SETS,
    SCORED_DIMENSION,
    coordinate_columns,
    matrix_values,
)
from estimators.base import Estimator, capabilities_of
from scenarios.fisher import InformationStatistics, frame_statistics
from scenarios.measurement_model import slant_range_m
from scenarios.signal import BurstPlan
from scenarios.simulate import noise_free
from scenarios.types import MeasurementSet, Scenario

if TYPE_CHECKING:  # annotations only: workers need not import the experiment schema
    from comparison.experiment import Experiment

Information = InformationStatistics
"""The Fisher information's statistics, one group per frame
(:func:`~scenarios.fisher.frame_statistics`)."""

CrlbKey = tuple[tuple[str, ...], Any]
"""The modalities (in a fixed order) and the ``frames`` option an estimator's bound uses."""


@dataclass(frozen=True, slots=True, kw_only=True)
class PointInfo:
    """One (scenario, point): its scenario, SNR, settings and Fisher information by modality."""

    scenario: Scenario
    snr_db: float
    settings: dict[str, float]
    information: dict[tuple[str, ...], Information | None]
    plan: BurstPlan | None = None
    """The bursts received at the point (the signal level), else None."""
    known_information: dict[tuple[str, ...], Information | None] = dataclasses.field(
        default_factory=dict
    )
    """The same with every nuisance parameter known (MATH §15): the scenario's unknowns'
    price; empty when the scenario has none (then ``information`` is it)."""

    @property
    def n_frames(self) -> int:
        return self.scenario.flight.n_frames

    @property
    def dimension(self) -> int:
        """``d``: the coordinates of the scenario's emitter a receiver estimates, those the
        bound is of (3 with the height unknown, MATH §8)."""
        return int(np.size(self.scenario.truth_emitter_m))

    def rmse_bound_m(self, modalities: tuple[str, ...], frame: int, frames: Any = "all") -> float:
        """√trace(CRLB) of ``modalities`` over the frames an estimator uses up to ``frame``."""
        return bound_of(self.information.get(modalities), frame, frames, self.dimension)

    def bound_columns(
        self,
        modalities: tuple[str, ...],
        frame: int,
        frames: Any = "all",
        kept: int | None = None,
    ) -> tuple[float, ...]:
        """:func:`bound_columns` of ``modalities`` over the frames an estimator uses."""
        return bound_columns(
            self.information.get(modalities), frame, frames, self.dimension, kept=kept
        )


def run_dimension(infos: Mapping[tuple[int, int], PointInfo]) -> int:
    """The coordinates a run's tables hold (:func:`~comparison.trial_rows.trials_table`): 3
    when an emitter's height is unknown at any point, else 2."""
    return max((info.dimension for info in infos.values()), default=SCORED_DIMENSION)


def information_of(
    info: Information | None, frame: int, frames: Any = "all", dimension: int | None = None
) -> np.ndarray:
    """The ``d × d`` Fisher information of the frames an estimator uses up to ``frame``
    (``"all"``, ``"last"`` or listed frames; MATH §8): that of the union of their samples, any
    nuisance parameter one over all of them (MATH §15). NaN without information or frames.

    ``d`` is the information's own (:attr:`~scenarios.fisher.InformationStatistics.dimension`);
    ``dimension`` gives it when there is no information (the emitter's coordinates;
    :data:`~comparison.trial_rows.SCORED_DIMENSION` when not given), and must agree with it
    otherwise."""
    d = _dimension(info, dimension)
    if info is None:
        return np.full((d, d), np.nan)
    if isinstance(frames, str) and frames == "last":
        chosen = [frame]
    elif isinstance(frames, Sequence) and not isinstance(frames, str):
        chosen = [int(f) for f in frames if 0 <= int(f) <= frame]
        if not chosen:
            return np.full((d, d), np.nan)
    else:
        chosen = list(range(frame + 1))
    return info.information(chosen)


def _dimension(info: Information | None, dimension: int | None) -> int:
    """The bound's ``d``: the information's, else ``dimension``, else the tables'."""
    if info is None:
        return SCORED_DIMENSION if dimension is None else int(dimension)
    if dimension is not None and dimension != info.dimension:
        raise ValueError(
            f"dimension: the information is of {info.dimension} coordinates, not {dimension}; "
            "compute it at the emitter's own coordinates"
        )
    return info.dimension


def bound_of(
    info: Information | None,
    frame: int,
    frames: Any = "all",
    dimension: int | None = None,
    *,
    horizontal_known: bool = False,
) -> float:
    """√trace(CRLB) over the frames an estimator uses up to ``frame`` (:func:`information_of`);
    with ``horizontal_known`` that of the ``(x, y)`` block of the information, the bound with
    the height known (MATH §8)."""
    information = information_of(info, frame, frames, dimension)
    if horizontal_known:
        information = information[:2, :2]
    return float(rmse_bound_m(information))


def bound_columns(
    info: Information | None,
    frame: int,
    frames: Any = "all",
    dimension: int | None = None,
    *,
    kept: int | None = None,
) -> tuple[float, ...]:
    """A row's bound columns: ``√trace(CRLB)``, then the CRLB's entries in m² in the order of
    :func:`~comparison.trial_rows.matrix_columns` (``xx, xy, yy`` for ``d = 2``: the
    :data:`~comparison.trial_rows.BOUND_COLUMNS`; for ``d = 3`` then ``xz, yz, zz``), over the
    frames an estimator uses up to ``frame`` (MATH §8); NaN where the information is singular
    or absent (``d`` as :func:`information_of` finds it). ``kept`` keeps the bound of the
    first coordinates only: ``(x, y)`` of the 3-D bound for an estimator that assumes the
    height it does not know (its horizontal answer is scored, against what the data allow)."""
    crlb = crlb_m2(information_of(info, frame, frames, dimension))
    if kept is not None:
        crlb = crlb[:kept, :kept]
    entries = matrix_values(crlb)
    return (float(np.sqrt(np.trace(crlb))), *(float(value) for value in entries))


def _modality_key(modalities: Iterable[str]) -> tuple[str, ...]:
    return tuple(m for m in ("toa", "doppler", "rss") if m in set(modalities))


def crlb_key(estimator: Estimator) -> CrlbKey:
    """The modalities and frames an estimator declares it uses: its bound's key (MATH §8)."""
    capabilities = capabilities_of(estimator)
    return _modality_key(capabilities.modalities), capabilities.frames


def information_at_truth(
    data: MeasurementSet,
    truth: Any,
    needed: Iterable[tuple[str, ...]],
    *,
    unknowns: Iterable[str] | None = None,
) -> dict[tuple[str, ...], Information | None]:
    """The per-frame statistics of the Fisher information of ``data``'s flight at the truth
    (:func:`~scenarios.fisher.frame_statistics`), per modality set (None where a σ or the RSS
    model is absent: no bound), with the nuisance parameters ``unknowns`` (default
    ``data.unknowns``) shared by whichever frames a bound uses (MATH §15)."""
    information: dict[tuple[str, ...], Information | None] = {}
    for modalities in needed:
        try:
            information[modalities] = frame_statistics(data, truth, modalities, unknowns=unknowns)
        except ValueError:  # a σ or the RSS model is absent: no bound
            information[modalities] = None
    return information


def point_infos(
    experiment: Experiment, crlb_keys: Iterable[CrlbKey]
) -> dict[tuple[int, int], PointInfo]:
    """Fisher information statistics per frame at the truth, for every modality set needed
    (MATH §8): those of the points table and those of the estimators' ``crlb_keys``."""
    needed = {_modality_key(m) for m in POINT_CRLB_SETS.values()}
    needed.update(modalities for modalities, _ in crlb_keys)
    infos = {}
    for i in range(len(experiment.scenarios)):
        for p, settings in enumerate(experiment.sweep.points()):
            scenario, snr_db = experiment.point_scenario(i, p)
            data = noise_free(scenario, snr_db=snr_db)
            truth = scenario.truth_emitter_m
            known = sorted({_modality_key(m) for m in POINT_KNOWN_CRLB_SETS.values()})
            infos[(i, p)] = PointInfo(
                scenario=scenario,
                snr_db=snr_db,
                settings=settings,
                information=information_at_truth(data, truth, sorted(needed)),
                plan=experiment.point_plan(p),
                known_information=information_at_truth(data, truth, known, unknowns=())
                if data.unknowns
                else {},
            )
    return infos


def point_rows(
    experiment: Experiment, infos: Mapping[tuple[int, int], PointInfo]
) -> list[dict[str, Any]]:
    """The rows of the points table, by column: truth, ``range_scale_m`` (the root mean square
    slant range of the samples flown so far) and the accumulated bounds of
    :data:`~comparison.trial_rows.POINT_CRLB_SETS`, per scenario × point × frame; in a 3-D run
    (:func:`run_dimension`) a 2-D scenario's ``truth_z_m`` is NaN, and with the height unknown
    the known bounds are those with the height known too."""
    dimension, nan = run_dimension(infos), math.nan
    rows = []
    for (i, p), info in infos.items():
        swept = {c: info.settings[c] for c in experiment.swept_columns}
        truth = [float(v) for v in info.scenario.truth_emitter_m]
        flight = info.scenario.flight
        squared_range = (
            slant_range_m(flight.sample_positions_m(), truth, info.scenario.emitter_height_m) ** 2
        )
        padding = dict.fromkeys(coordinate_columns("truth_{}_m", dimension)[len(truth) :], nan)
        for frame in range(info.n_frames):
            bounds = {
                column: info.rmse_bound_m(_modality_key(modalities), frame)
                for column, modalities in POINT_CRLB_SETS.items()
            }
            for column, modalities in POINT_KNOWN_CRLB_SETS.items():
                key = _modality_key(modalities)
                known = info.known_information.get(key, info.information.get(key))
                bounds[column] = bound_of(known, frame, horizontal_known=info.dimension > 2)
            if dimension > 2:  # the parts of the 3-D bound (the whole of a 2-D one)
                crlb = crlb_m2(information_of(info.information.get(("toa", "doppler")), frame))
                horizontal, vertical = crlb_parts_m(crlb)
                bounds.update(zip(POINT_HEIGHT_CRLB, (horizontal, vertical), strict=True))
            scale = math.sqrt(float(np.mean(squared_range[flight.sample_frames() <= frame])))
            rows.append(
                {
                    "scenario": experiment.scenarios[i],
                    "point": p,
                    "frame": frame,
                    "scenario_index": i,
                    "snr_db": info.snr_db,
                    **swept,
                    **dict(zip(coordinate_columns("truth_{}_m", len(truth)), truth, strict=True)),
                    **padding,
                    "range_scale_m": scale,
                    **bounds,
                }
            )
    return rows
