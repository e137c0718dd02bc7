"""What a cross-check found: the per-family summaries, the result with its ``validate.json``
content, and the command line that replays one instance."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from comparison.crosscheck.compare import InstanceResult


def replay_command(result: InstanceResult, estimator_args: str = "") -> str:
    """The command line that re-runs ``result``'s instance verbosely."""
    command = f"emitterbench validate --replay {result.seed} --families {result.family}"
    return f"{command} {estimator_args}" if estimator_args else command


# --------------------------------------------------------------------------------------------
# a run over families
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class FamilySummary:
    """Aggregates of one family (the per-family block of ``validate.json``).

    ``n_sdp_failed`` counts instances whose SDP did not end with status ``optimal`` (each is a
    disagreement). ``dimension`` is the family's emitter coordinates: 2 (``r = (x, y,
    x² + y²)``) or 3 (the height unknown, ``r = (x, y, z, x² + y² + z²)``). The
    ``*estimator*`` fields are set when an estimator was validated: instances where it failed
    or raised, the largest relative cost gap and distance of its candidates, and the total of
    missing and extra candidates (:class:`CandidateCheck`).
    """

    family: str
    dimension: int
    n: int
    n_hard: int
    n_unique: int
    n_disagreements: int
    max_rel_objective_gap: float
    max_argmin_distance_m: float
    max_argmin_distance_rel: float
    max_candidate_pair_distance_m: float
    max_candidate_pair_distance_rel: float
    statuses: dict[str, int]
    tolerance_rungs: dict[str, int]
    median_closed_form_time_s: float
    median_sdp_time_s: float
    n_multiplier_nonnegative: int = 0
    n_inequality_tight_when_nonnegative: int = 0
    max_inequality_gap_when_nonnegative: float = float("nan")
    n_multiplier_negative: int = 0
    n_inequality_loose_when_negative: int = 0
    min_inequality_gap_when_negative: float = float("nan")
    n_sdp_failed: int = 0
    n_estimator_failed: int = 0
    max_estimator_rel_cost_gap: float = float("nan")
    max_estimator_distance_m: float = float("nan")
    max_estimator_distance_rel: float = float("nan")
    n_estimator_missing: int = 0
    n_estimator_extra: int = 0


@dataclass(frozen=True, slots=True, eq=False)
class ValidationResult:
    """What :func:`run_validation` found; ``ok`` is false when any instance disagrees.

    ``estimator`` is the validated estimator's name (None: the built-in closed form on the
    families' rows) and ``estimator_args`` the ``--estimator ... --option ...`` arguments that
    rebuild it in a replay command. ``skipped`` maps a family not run to why (an estimator
    that takes the emitter's height as known, on a family of dimension 3).
    """

    seed: int
    rtol_objective: float
    rtol_argmin: float
    families: dict[str, FamilySummary]
    results: tuple[InstanceResult, ...]
    files: dict[str, Path] = field(default_factory=dict)
    estimator: str | None = None
    estimator_args: str = ""
    skipped: dict[str, str] = field(default_factory=dict)

    def replay_command(self, result: InstanceResult) -> str:
        """The command line that re-runs one instance of this validation verbosely."""
        return replay_command(result, self.estimator_args)

    @property
    def disagreements(self) -> tuple[InstanceResult, ...]:
        return tuple(result for result in self.results if not result.agrees)

    @property
    def ok(self) -> bool:
        return not self.disagreements

    def to_dict(self) -> dict[str, Any]:
        """The content of ``validate.json`` (NaN becomes None)."""
        import cvxpy

        try:
            from importlib.metadata import version

            clarabel_version = version("clarabel")
        except Exception:  # pragma: no cover - metadata missing
            clarabel_version = None
        return json_clean(
            {
                "ok": self.ok,
                "seed": self.seed,
                "estimator": None
                if self.estimator is None
                else {"name": self.estimator, "args": self.estimator_args},
                "tolerances": {
                    "rel_objective_gap": self.rtol_objective,
                    "argmin_distance_rel": self.rtol_argmin,
                },
                "relaxation": "equality (Shor, MATH §11)",
                "versions": {"cvxpy": cvxpy.__version__, "clarabel": clarabel_version},
                "families": {name: asdict(summary) for name, summary in self.families.items()},
                **({"skipped_families": dict(self.skipped)} if self.skipped else {}),
                "disagreements": [
                    {
                        "family": r.family,
                        "seed": r.seed,
                        "reasons": list(r.reasons),
                        "status": r.status,
                        "hard_case": r.hard_case,
                        "rel_objective_gap": r.rel_objective_gap,
                        "argmin_distance_m": r.argmin_distance_m,
                        "pair_distance_m": r.pair_distance_m,
                        "candidates": None if r.candidates is None else asdict(r.candidates),
                        "replay": self.replay_command(r),
                    }
                    for r in self.disagreements
                ],
            }
        )


def json_clean(value: Any) -> Any:
    """``value`` as JSON holds it: NaN and infinities as None, numpy scalars as Python ones."""
    if isinstance(value, dict):
        return {str(k): json_clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_clean(v) for v in value]
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer | np.bool_):
        return value.item()
    return value
