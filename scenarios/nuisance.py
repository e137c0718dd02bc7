"""The nuisance parameters of a non-cooperative emitter (MATH §15).

A cooperative emitter's carrier and emission time are known. An unknown transmitter (a lost
beacon, an interferer) gives neither:

- ``carrier_offset_hz``, δ: its carrier is off the nominal ``f0`` by an unknown constant, so every
  Doppler sample carries it, ``f_k = −γ v_kᵀu_k + δ + w_k``;
- ``emission_time_s``, b: it emits at an unknown time, so every one-way ToA carries it,
  ``τ_k = ρ_k/c + b + n_k`` (pseudo-ranges ``c τ_k = ρ_k + c b``).

Both are constant over a pass. A scenario sets their true values and which of them the
estimators must treat as unknown; a :class:`~scenarios.types.MeasurementSet` carries the names
of the unknown ones (``unknowns``) and, in simulations, their true values. A known offset is
one the receiver corrects for, so a simulation applies an offset only when it is declared
unknown: with ``unknowns`` empty every estimator sees a cooperative emitter, as before.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from scenarios.fields import bounded

NUISANCE_PARAMETERS: tuple[str, ...] = ("carrier_offset_hz", "emission_time_s")
"""The nuisance parameters, in the order of their columns in the Fisher information (MATH §15)."""

HEIGHT_UNKNOWN = "emitter_height_m"
"""The emitter's height as an unknown: not a nuisance parameter but a third coordinate of the
position (MATH §7, §8), so the position has :func:`position_dimension` coordinates. With it
unknown a measurement set's ``emitter_height_m`` is the height an estimator that ignores the
unknown assumes (the take-off ground, 0, unless given) and the truth has three coordinates."""

UNKNOWNS: tuple[str, ...] = (*NUISANCE_PARAMETERS, HEIGHT_UNKNOWN)
"""Everything ``unknowns`` may name, in canonical order."""

AFFECTED_MODALITY: dict[str, str] = {"carrier_offset_hz": "doppler", "emission_time_s": "toa"}
"""The one modality each nuisance parameter enters."""

MAX_CARRIER_OFFSET_HZ = 1e12
"""Largest accepted ``|δ|``: beyond the carrier range of :mod:`scenarios.types`."""

MAX_EMISSION_TIME_S = 1e12
"""Largest accepted ``|b|``, the time limit of :mod:`scenarios.types`."""


def parse_unknowns(value: Iterable[str] | str | None, field: str = "unknowns") -> tuple[str, ...]:
    """``value`` as a tuple of the names of :data:`UNKNOWNS` in the canonical order.

    ``None`` and an empty list mean all are known (a cooperative emitter at a known height).
    Raises ``ValueError`` naming ``field`` for anything but a list of names of
    :data:`UNKNOWNS`.
    """
    if value is None:
        return ()
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list | tuple | set | frozenset):
        raise ValueError(
            f"{field}: expected a list of any of {list(UNKNOWNS)}, got {type(value).__name__}"
        )
    names = list(value)
    wrong = [name for name in names if not isinstance(name, str) or name not in UNKNOWNS]
    if wrong:
        raise ValueError(f"{field}: expected a list of any of {list(UNKNOWNS)}, got {wrong[0]!r}")
    return tuple(name for name in UNKNOWNS if name in names)


def nuisance_unknowns(unknowns: Iterable[str]) -> tuple[str, ...]:
    """The nuisance parameters among ``unknowns`` (:data:`NUISANCE_PARAMETERS`: the height,
    a coordinate of the position, is not one)."""
    return tuple(name for name in parse_unknowns(unknowns) if name in AFFECTED_MODALITY)


def position_dimension(unknowns: Iterable[str]) -> int:
    """The position's coordinates: 3, ``(x_s, y_s, z_s)``, with the height unknown, else 2."""
    return 3 if HEIGHT_UNKNOWN in parse_unknowns(unknowns) else 2


def math_sections(unknowns: Iterable[str]) -> str:
    """Where docs/math.md treats these unknowns: ``"MATH §8"`` the height (a coordinate of the
    position), ``"MATH §15"`` the nuisance parameters, ``"MATH §8, §15"`` both."""
    names = parse_unknowns(unknowns)
    cited = (("§8", HEIGHT_UNKNOWN in names), ("§15", bool(nuisance_unknowns(names))))
    return "MATH " + ", ".join(section for section, wanted in cited if wanted)


def unknowns_used(unknowns: Iterable[str], modalities: Iterable[str]) -> tuple[str, ...]:
    """The unknowns that enter the given modalities (δ only with Doppler, b only with ToA, the
    height with every one)."""
    used = set(modalities)
    return tuple(
        name
        for name in parse_unknowns(unknowns)
        if (AFFECTED_MODALITY[name] in used if name in AFFECTED_MODALITY else bool(used))
    )


def describe_unknowns(unknowns: Iterable[str]) -> str:
    """``"carrier offset and emission time"``: the unknowns in words, or ``"none"``."""
    words = {
        "carrier_offset_hz": "carrier offset",
        "emission_time_s": "emission time",
        HEIGHT_UNKNOWN: "height",
    }
    names = [words[name] for name in parse_unknowns(unknowns)]
    return " and ".join(names) if names else "none"


def set_nuisance_fields(obj: Any, prefix: str, label: str) -> None:
    """Check and store, on a frozen ``Scenario`` or ``MeasurementSet``, ``unknowns`` and the
    values ``<prefix>carrier_offset_hz`` and ``<prefix>emission_time_s`` (None: not given);
    errors name them ``<label>carrier_offset_hz``."""
    object.__setattr__(obj, "unknowns", parse_unknowns(obj.unknowns))
    for name, limit, unit in (
        ("carrier_offset_hz", MAX_CARRIER_OFFSET_HZ, "Hz"),
        ("emission_time_s", MAX_EMISSION_TIME_S, "s"),
    ):
        value = getattr(obj, prefix + name)
        if value is not None:
            number = bounded(value, label + name, -limit, limit, unit, "check the unit")
            object.__setattr__(obj, prefix + name, number)


__all__ = [
    "AFFECTED_MODALITY",
    "HEIGHT_UNKNOWN",
    "MAX_CARRIER_OFFSET_HZ",
    "MAX_EMISSION_TIME_S",
    "NUISANCE_PARAMETERS",
    "UNKNOWNS",
    "describe_unknowns",
    "math_sections",
    "nuisance_unknowns",
    "parse_unknowns",
    "position_dimension",
    "set_nuisance_fields",
    "unknowns_used",
]
