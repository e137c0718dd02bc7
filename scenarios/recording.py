"""SigMF recordings of bursts: the received samples of one trial, with the UAV's track and the
truth in a namespaced extension (the signal model of MATH §18).

A recording ``REC`` is two files, the SigMF pair:

- ``REC.sigmf-data``: ``cf32_le`` samples (complex64, little-endian), the windows of the
  bursts one after the other, burst ``k`` at sample ``k · n_samples`` (``n_samples`` the
  window of :class:`~scenarios.signal.BurstPlan`: the burst and its two guards);
- ``REC.sigmf-meta``: JSON checked against the SigMF schema by the ``sigmf`` package.
  ``core:sample_rate`` is the plan's rate, ``core:frequency`` of every capture the nominal
  carrier ``f0 = γ c`` the receiver is tuned to. One capture per burst window
  (``core:sample_start = k · n_samples``, ``emitterbench:time_s`` the time of its first
  sample), one annotation per burst (its samples without the guards, ``core:label`` ``burst
  k``, ``emitterbench:emission_time_s`` its nominal emission time).

The global object declares the extension ``emitterbench`` (``core:extensions``) and holds:

``emitterbench:plan``
    Every field of :class:`~scenarios.signal.BurstPlan`: ``waveform``, ``burst_s``,
    ``sample_rate_hz``, ``cn0_dbhz``, ``chip_rate_hz`` (null for a tone), ``chip_seed``,
    ``received_power_w``, ``guard_s``.
``emitterbench:track``
    One entry per burst: ``frame``, ``time_s`` (``t_k``, when burst ``k``'s centre reaches the
    UAV, the centre of its window), ``position_m`` and ``velocity_mps`` (``(3,)`` each, the
    UAV's at ``t_k``; a frame is flown at one velocity, MATH §0).
``emitterbench:constants``
    ``gamma_per_m`` (``f0 / c``), ``speed_of_light_mps``, ``emitter_height_m``, ``unknowns``
    (what the receiver does not know, MATH §15, §8) and, when known, ``terrain``.
``emitterbench:emission_time_s``
    The schedule ``e_k``, one per burst: the nominal emission times a cooperative receiver
    knows (MATH §18); a delay is measured from them.
``emitterbench:truth`` (absent when unknown)
    ``emitter_m``, and beside it ``carrier_offset_hz`` and ``emission_time_s`` when they are
    unknowns of the receiver.
``emitterbench:trial``
    Which trial of the simulation the samples are.

Floats are written with ``repr`` precision, so the track, the plan and the schedule read back
bit for bit. :func:`open_recording` checks the metadata against the SigMF schema, then the
fields above, then the data file's size and, when ``core:sha512`` is given, its hash (the bytes
streamed 4 KiB at a time); :meth:`Recording.bursts` reads the samples a block of bursts at a
time, never the whole file. Every error is one
``ValueError`` line naming the field (``emitterbench:track.position_m``, ``core:datatype``,
the data file) and the fix.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from scenarios.fields import frozen_array, number, text, whole
from scenarios.limits import load_json, read_text, write_text_atomically
from scenarios.nuisance import parse_unknowns, position_dimension
from scenarios.signal import BurstPlan, ReceivedBursts, noise_at_cn0
from scenarios.terrain import Terrain
from scenarios.types import MeasurementSet

NAMESPACE = "emitterbench"
"""The SigMF extension namespace of the recordings' own fields."""
EXTENSION_VERSION = "1.0.0"
"""The version of the ``emitterbench`` extension this module writes and reads."""
DATATYPE = "cf32_le"
"""The one sample format written and read: complex float32, little-endian."""
SAMPLE_DTYPE = np.dtype("<c8")
"""numpy's name for :data:`DATATYPE`."""
META_SUFFIX = ".sigmf-meta"
DATA_SUFFIX = ".sigmf-data"

PLAN_FIELDS = tuple(f.name for f in fields(BurstPlan) if f.init)
"""The fields of ``emitterbench:plan``: every parameter of :class:`BurstPlan`."""
TRACK_FIELDS = ("frame", "time_s", "position_m", "velocity_mps")
CONSTANT_FIELDS = ("gamma_per_m", "speed_of_light_mps", "emitter_height_m", "unknowns")
_TRUTH_OPTIONAL = ("carrier_offset_hz", "emission_time_s")
_GAMMA_RTOL = 1e-12

FloatArray = NDArray[np.float64]


def recording_paths(path: str | os.PathLike[str]) -> tuple[Path, Path]:
    """``(REC.sigmf-meta, REC.sigmf-data)`` of ``REC``, given with or without either
    suffix."""
    path = Path(path)
    base = path.with_suffix("") if path.suffix in (META_SUFFIX, DATA_SUFFIX) else path
    return base.with_name(base.name + META_SUFFIX), base.with_name(base.name + DATA_SUFFIX)


# --------------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------------


def recording_metadata(
    geometry: MeasurementSet, plan: BurstPlan, emission_time_s: FloatArray, trial: int = 0
) -> dict[str, Any]:
    """The SigMF metadata (``global``, ``captures``, ``annotations``) of a recording of the
    bursts of ``plan`` flown along ``geometry``, with the schedule ``emission_time_s``."""
    n_bursts, n = geometry.n_samples, plan.n_samples
    schedule = frozen_array(emission_time_s, "emission_time_s", (n_bursts,))
    truth: dict[str, Any] | None = None
    if geometry.truth_emitter_m is not None:
        truth = {"emitter_m": geometry.truth_emitter_m.tolist()}
        for name in _TRUTH_OPTIONAL:
            value = getattr(geometry, f"truth_{name}")
            if value is not None:
                truth[name] = value
    constants: dict[str, Any] = {
        "gamma_per_m": geometry.gamma_per_m,
        "speed_of_light_mps": geometry.speed_of_light_mps,
        "emitter_height_m": geometry.emitter_height_m,
        "unknowns": list(geometry.unknowns),
    }
    if geometry.terrain is not None:
        constants["terrain"] = geometry.terrain.as_dict()
    first_sample_s = geometry.time_s - (n - 1) / 2.0 / plan.sample_rate_hz
    description = (
        f"{n_bursts} {plan.waveform} bursts of {plan.burst_s:g} s received by a moving UAV at "
        f"C/N0 {plan.cn0_dbhz:g} dB-Hz, trial {trial}; the track, the schedule and the truth "
        f"are in the {NAMESPACE} extension"
    )
    global_info: dict[str, Any] = {
        "core:datatype": DATATYPE,
        "core:sample_rate": plan.sample_rate_hz,
        "core:description": description,
        "core:recorder": NAMESPACE,
        "core:extensions": [{"name": NAMESPACE, "version": EXTENSION_VERSION, "optional": True}],
        f"{NAMESPACE}:plan": {name: getattr(plan, name) for name in PLAN_FIELDS},
        f"{NAMESPACE}:track": {
            "frame": geometry.frame.tolist(),
            "time_s": geometry.time_s.tolist(),
            "position_m": geometry.position_m.tolist(),
            "velocity_mps": geometry.velocity_mps.tolist(),
        },
        f"{NAMESPACE}:constants": constants,
        f"{NAMESPACE}:emission_time_s": schedule.tolist(),
        f"{NAMESPACE}:trial": int(trial),
    }
    if truth is not None:
        global_info[f"{NAMESPACE}:truth"] = truth
    captures = [
        {
            "core:sample_start": k * n,
            "core:frequency": geometry.carrier_hz,
            f"{NAMESPACE}:time_s": float(first_sample_s[k]),
        }
        for k in range(n_bursts)
    ]
    annotations = [
        {
            "core:sample_start": k * n + plan.n_guard_samples,
            "core:sample_count": plan.n_burst_samples,
            "core:label": f"burst {k}",
            f"{NAMESPACE}:emission_time_s": float(schedule[k]),
        }
        for k in range(n_bursts)
    ]
    return {"global": global_info, "captures": captures, "annotations": annotations}


def write_recording(
    path: str | os.PathLike[str],
    geometry: MeasurementSet,
    plan: BurstPlan,
    received: ReceivedBursts,
    trial: int = 0,
) -> tuple[Path, Path]:
    """Write trial ``trial`` of ``received`` as the SigMF recording ``path``; returns
    ``(meta_path, data_path)``.

    ``geometry`` is the flight and the truth the bursts were drawn from (one burst per sample,
    e.g. :func:`scenarios.simulate.noise_free` of the scenario), ``plan`` their plan. The
    metadata is checked against the SigMF schema before anything is written; the data file is
    written next, then the metadata (with the data's SHA-512), atomically.
    """
    from sigmf import SigMFFile

    meta_path, data_path = recording_paths(path)
    if not isinstance(geometry, MeasurementSet):
        raise ValueError(f"geometry: expected a MeasurementSet, got {type(geometry).__name__}")
    if not isinstance(received, ReceivedBursts):
        raise ValueError(f"received: expected ReceivedBursts, got {type(received).__name__}")
    n_trials, n_bursts, n = received.samples.shape
    if (n_bursts, n) != (geometry.n_samples, plan.n_samples):
        raise ValueError(
            f"received: samples of shape {received.samples.shape} do not fit {geometry.n_samples} "
            f"bursts of {plan.n_samples} samples; draw them from this geometry and plan"
        )
    trial = whole(trial, "trial", minimum=0)
    if trial >= n_trials:
        raise ValueError(f"trial: {trial} is beyond the {n_trials} trial(s) drawn")
    if not meta_path.parent.is_dir():
        raise ValueError(f"output: folder {meta_path.parent} does not exist; create it first")
    metadata = recording_metadata(geometry, plan, received.emission_time_s, trial)
    handle = SigMFFile(metadata=metadata)
    handle.validate()
    try:
        received.samples[trial].astype(SAMPLE_DTYPE).tofile(data_path)
    except OSError as error:
        raise ValueError(f"output: cannot write {data_path} ({error.strerror or error})") from None
    handle.set_data_file(data_path)  # the SHA-512 of the data, in core:sha512
    write_text_atomically(handle.dumps() + "\n", meta_path)
    return meta_path, data_path


# --------------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Recording:
    """An opened recording (:func:`open_recording`): what the front end and a direct estimator
    need besides the samples, which :meth:`bursts` reads from disk a block at a time.

    ``geometry`` is the flight, the constants and the truth, as a
    :class:`~scenarios.types.MeasurementSet` of one sample per burst whose measurements are the
    nominal ones the schedule gives before anything is measured: a Doppler of 0 (the nominal
    carrier) and a ToA of ``t_k − e_k`` (each burst arriving at its window's centre; no ToA
    for a tone, which carries no delay), labelled with the σ's of the plan's bounds at its C/N0
    (MATH §18). A front end replaces them with what it measures.
    """

    meta_path: Path
    data_path: Path
    plan: BurstPlan
    geometry: MeasurementSet
    emission_time_s: FloatArray
    trial: int

    @property
    def n_bursts(self) -> int:
        return self.geometry.n_samples

    def bursts(self, block: int = 64) -> Iterator[tuple[int, NDArray[np.complex128]]]:
        """``(first_burst_index, samples)`` of ``block`` bursts at a time (fewer at the end),
        ``samples`` ``(b, n_samples)`` complex128, each block read from the data file alone."""
        block = whole(block, "block", minimum=1)
        n = self.plan.n_samples
        for first in range(0, self.n_bursts, block):
            count = min(block, self.n_bursts - first) * n
            samples = np.fromfile(
                self.data_path,
                dtype=SAMPLE_DTYPE,
                count=count,
                offset=first * n * SAMPLE_DTYPE.itemsize,
            )
            if samples.size != count:
                raise ValueError(
                    f"{self.data_path}: ended at burst {first + samples.size // n} of "
                    f"{self.n_bursts} while reading; the file changed since it was opened"
                )
            yield first, samples.astype(np.complex128).reshape(-1, n)


def open_recording(meta_path: str | os.PathLike[str]) -> Recording:
    """Open the recording ``meta_path`` (``REC.sigmf-meta``, or ``REC``) and check it whole:
    the SigMF schema, ``core:datatype``, the ``emitterbench`` fields, the data file's size and
    its SHA-512 (streamed 4 KiB at a time; no sample is kept)."""
    from sigmf import SigMFFile

    meta_path, data_path = recording_paths(meta_path)
    metadata = load_json(read_text(meta_path), source=str(meta_path))
    if not isinstance(metadata, dict) or not isinstance(metadata.get("global"), dict):
        raise ValueError(f"{meta_path}: not SigMF metadata (no global object); give a .sigmf-meta")
    try:
        SigMFFile(metadata=metadata).validate()
    except Exception as error:  # jsonschema's ValidationError, or sigmf's own
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise ValueError(
            f"{meta_path}: fails the SigMF schema ({reason}); fix the metadata"
        ) from None
    header = metadata["global"]
    datatype = header.get("core:datatype")
    if datatype != DATATYPE:
        raise ValueError(
            f"core:datatype: expected {DATATYPE!r} (complex float32, little-endian), got "
            f"{datatype!r}; convert the samples to {DATATYPE}"
        )
    if header.get("core:num_channels", 1) != 1:
        raise ValueError("core:num_channels: expected 1 channel; split the recording")
    plan = _plan(_field(header, "plan", dict))
    rate = number(header.get("core:sample_rate"), "core:sample_rate")
    if rate != plan.sample_rate_hz:
        raise ValueError(
            f"core:sample_rate: {rate!r} differs from {NAMESPACE}:plan.sample_rate_hz "
            f"{plan.sample_rate_hz!r}; make them equal"
        )
    captures = metadata.get("captures") or []
    carrier_hz = _carrier_hz(captures, plan)
    track = _field(header, "track", dict)
    n_bursts = len(_column(track, "frame"))
    if len(captures) != n_bursts:
        raise ValueError(
            f"captures: {len(captures)} capture(s) for {n_bursts} bursts; write one per burst "
            "window"
        )
    schedule = frozen_array(
        _field(header, "emission_time_s", list),
        f"{NAMESPACE}:emission_time_s",
        (n_bursts,),
    )
    geometry = _geometry(header, track, carrier_hz, schedule, plan)
    trial = whole(header.get(f"{NAMESPACE}:trial", 0), f"{NAMESPACE}:trial", minimum=0)
    _check_data_size(data_path, n_bursts, plan.n_samples)
    _check_hash(header.get("core:sha512"), data_path)
    return Recording(meta_path, data_path, plan, geometry, schedule, trial)


def _field(header: Mapping[str, Any], name: str, kind: type) -> Any:
    """``emitterbench:<name>`` of the global object, of type ``kind``."""
    key = f"{NAMESPACE}:{name}"
    if key not in header:
        raise ValueError(
            f"{key}: missing; this recording has no {name} of the {NAMESPACE} extension "
            "(write it with emitterbench simulate-iq, or add the field)"
        )
    value = header[key]
    if not isinstance(value, kind):
        expected = "an object" if kind is dict else "a list"
        raise ValueError(f"{key}: expected {expected}, got {type(value).__name__}")
    return value


def _plan(obj: Mapping[str, Any]) -> BurstPlan:
    path = f"{NAMESPACE}:plan"
    missing = [name for name in PLAN_FIELDS if name not in obj]
    if missing:
        raise ValueError(f"{path}.{missing[0]}: missing; the plan needs {', '.join(PLAN_FIELDS)}")
    unknown = sorted(set(obj) - set(PLAN_FIELDS))
    if unknown:
        raise ValueError(f"{path}.{unknown[0]}: unknown field; expected {', '.join(PLAN_FIELDS)}")
    values = dict(obj)
    for name in PLAN_FIELDS:
        if name == "waveform":
            values[name] = text(values[name], f"{path}.waveform")
        elif name == "chip_seed":
            values[name] = whole(values[name], f"{path}.chip_seed", minimum=0)
        elif values[name] is not None or name != "chip_rate_hz":
            values[name] = number(values[name], f"{path}.{name}")
    return _prefixed(path, lambda: BurstPlan(**values))


def _carrier_hz(captures: list[Any], plan: BurstPlan) -> float:
    """The nominal carrier, ``core:frequency`` of every capture; and each capture at its
    window (``core:sample_start = k · n_samples``)."""
    carriers = set()
    for k, capture in enumerate(captures):
        start = capture.get("core:sample_start")
        if start != k * plan.n_samples:
            raise ValueError(
                f"captures[{k}].core:sample_start: expected {k * plan.n_samples} (burst {k} "
                f"at {k} × {plan.n_samples} samples), got {start!r}; write one capture per "
                "burst window"
            )
        if "core:frequency" not in capture:
            raise ValueError(
                f"captures[{k}].core:frequency: missing; give the nominal carrier (Hz)"
            )
        carriers.add(number(capture["core:frequency"], f"captures[{k}].core:frequency"))
    if len(carriers) != 1:
        raise ValueError(
            "captures.core:frequency: every burst needs the same nominal carrier, got "
            f"{sorted(carriers) or 'none'}"
        )
    return carriers.pop()


def _column(track: Mapping[str, Any], name: str) -> list[Any]:
    path = f"{NAMESPACE}:track.{name}"
    if name not in track:
        raise ValueError(f"{path}: missing; the track needs {', '.join(TRACK_FIELDS)}")
    value = track[name]
    if not isinstance(value, list) or not value:
        raise ValueError(f"{path}: expected a list with one entry per burst, got {value!r:.40}")
    return value


def _geometry(
    header: Mapping[str, Any],
    track: Mapping[str, Any],
    carrier_hz: float,
    schedule: FloatArray,
    plan: BurstPlan,
) -> MeasurementSet:
    prefix = f"{NAMESPACE}:track"
    unknown = sorted(set(track) - set(TRACK_FIELDS))
    if unknown:
        raise ValueError(
            f"{prefix}.{unknown[0]}: unknown field; expected {', '.join(TRACK_FIELDS)}"
        )
    n = len(schedule)
    columns = {
        "frame": frozen_array(_column(track, "frame"), f"{prefix}.frame", (n,)),
        "time_s": frozen_array(_column(track, "time_s"), f"{prefix}.time_s", (n,)),
        "position_m": frozen_array(_column(track, "position_m"), f"{prefix}.position_m", (n, 3)),
        "velocity_mps": frozen_array(
            _column(track, "velocity_mps"), f"{prefix}.velocity_mps", (n, 3)
        ),
    }
    constants = _field(header, "constants", dict)
    path = f"{NAMESPACE}:constants"
    missing = [name for name in CONSTANT_FIELDS if name not in constants]
    if missing:
        raise ValueError(f"{path}.{missing[0]}: missing; give {', '.join(CONSTANT_FIELDS)}")
    c = number(constants["speed_of_light_mps"], f"{path}.speed_of_light_mps")
    gamma = number(constants["gamma_per_m"], f"{path}.gamma_per_m")
    if abs(gamma * c - carrier_hz) > _GAMMA_RTOL * abs(carrier_hz):
        raise ValueError(
            f"{path}.gamma_per_m: {gamma!r} × c = {gamma * c!r} Hz is not the captures' carrier "
            f"core:frequency {carrier_hz!r} Hz; make gamma_per_m = core:frequency / c"
        )
    unknowns = parse_unknowns(constants["unknowns"], f"{path}.unknowns")
    terrain = None
    if constants.get("terrain") is not None:
        if not isinstance(constants["terrain"], dict):
            raise ValueError(f"{path}.terrain: expected an object of Terrain's fields")
        terrain = _prefixed(path, lambda: Terrain(**constants["terrain"]))
    truth = _truth(header.get(f"{NAMESPACE}:truth"), position_dimension(unknowns))
    nominal = {"doppler_hz": np.zeros(n)}
    if plan.waveform != "cw":
        nominal["toa_s"] = columns["time_s"] - schedule
    return _prefixed(
        prefix,
        lambda: MeasurementSet(
            **columns,
            **nominal,
            carrier_hz=carrier_hz,
            speed_of_light_mps=c,
            emitter_height_m=number(constants["emitter_height_m"], f"{path}.emitter_height_m"),
            noise=noise_at_cn0(plan),
            unknowns=unknowns,
            terrain=terrain,
            **truth,
        ),
    )


def _truth(obj: Any, dimension: int) -> dict[str, Any]:
    path = f"{NAMESPACE}:truth"
    if obj is None:
        return {}
    if not isinstance(obj, dict) or "emitter_m" not in obj:
        raise ValueError(f'{path}: expected an object {{"emitter_m": [...]}}, got {obj!r:.40}')
    unknown = sorted(set(obj) - {"emitter_m", *_TRUTH_OPTIONAL})
    if unknown:
        raise ValueError(
            f"{path}.{unknown[0]}: unknown field; expected emitter_m and any of "
            f"{', '.join(_TRUTH_OPTIONAL)}"
        )
    truth = {"truth_emitter_m": frozen_array(obj["emitter_m"], f"{path}.emitter_m", (dimension,))}
    for name in _TRUTH_OPTIONAL:
        if name in obj:
            truth[f"truth_{name}"] = number(obj[name], f"{path}.{name}")
    return truth


def _prefixed(prefix: str, build: Any) -> Any:
    """``build()``, its one-line ``ValueError`` prefixed with ``prefix`` (a field path)."""
    try:
        return build()
    except ValueError as error:
        raise ValueError(f"{prefix}.{error}") from None


def _check_hash(expected: Any, data_path: Path) -> None:
    """The data file's SHA-512 against ``core:sha512`` when given (read 4 KiB at a time)."""
    from sigmf.hashing import calculate_sha512

    if expected is not None and calculate_sha512(filename=data_path) != expected:
        raise ValueError(
            f"core:sha512: differs from the hash of {data_path}; the samples changed since the "
            "metadata was written (copy the pair again, or drop core:sha512 to accept them)"
        )


def _check_data_size(data_path: Path, n_bursts: int, n_samples: int) -> None:
    expected = n_bursts * n_samples
    try:
        size = data_path.stat().st_size
    except FileNotFoundError:
        raise ValueError(
            f"{data_path}: missing; a recording's samples are in REC{DATA_SUFFIX} beside "
            f"REC{META_SUFFIX} (copy both)"
        ) from None
    held, remainder = divmod(size, SAMPLE_DTYPE.itemsize)
    if held != expected or remainder:
        what = "truncated" if size < expected * SAMPLE_DTYPE.itemsize else "too long"
        raise ValueError(
            f"{data_path}: holds {size} bytes ({held} samples), the recording needs {n_bursts} "
            f"bursts × {n_samples} samples = {expected} ({expected * SAMPLE_DTYPE.itemsize} "
            f"bytes); the file is {what} (copy it again)"
        )
