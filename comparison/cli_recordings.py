"""The commands on SigMF recordings of bursts (:mod:`scenarios.recording`): ``simulate-iq``
writes one, ``measure`` runs the front end over one and writes the measurement file
``estimate`` reads (which reads a recording too, :func:`comparison.cli_support.load_measurements`).

Registered in :mod:`comparison.cli` like its own commands; heavy imports stay in the bodies.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any

import typer

from comparison.cli_support import (
    DopplerSearchOption,
    flags_for,
    known_scenario,
    measured_recording,
)

DOPPLER_CYCLES_PER_BURST = 0.1
"""The most ``|f| T`` a BPSK burst is measured well at without a Doppler search: the front
end's first delay pass then correlates with the chips at zero Doppler, and loses 3% of the
energy at 0.1 (MATH §20)."""
SEARCH_MARGIN = 1.1
"""The Doppler search ``simulate-iq`` suggests: the bursts' largest ``|f|`` times this, rounded
up to two significant digits."""
IQ_SAMPLES = (20_000_000, "EMITTERBENCH_MAX_IQ_SAMPLES")
"""Most samples ``simulate-iq`` draws (bursts × window): 320 MB as complex128, about five
times that while drawing; the file holds half the first (cf32_le)."""


def simulate_iq_command(
    scenario: Annotated[
        str,
        typer.Argument(help="Scenario name (see `emitterbench list`).", callback=known_scenario),
    ],
    seed: Annotated[int, typer.Option("--seed", min=0, help="Seed of the phases and noise.")],
    cn0_dbhz: Annotated[
        float, typer.Option("--cn0-dbhz", help="Carrier-to-noise density C/N0, dB-Hz (MATH §18).")
    ],
    output: Annotated[
        Path,
        typer.Option(
            "--output", "-o", help="Recording to write: REC gives REC.sigmf-meta, REC.sigmf-data."
        ),
    ],
    waveform: Annotated[
        str, typer.Option("--waveform", metavar="bpsk|cw", help="The burst: BPSK chips or a tone.")
    ] = "bpsk",
    burst_s: Annotated[float, typer.Option("--burst-s", help="Burst length T, s.")] = 1e-2,
    sample_rate_hz: Annotated[
        float, typer.Option("--sample-rate-hz", help="Complex sample rate fs, Hz.")
    ] = 4e5,
    chip_rate_hz: Annotated[
        float, typer.Option("--chip-rate-hz", help="BPSK chip rate, chips/s (not used by cw).")
    ] = 1e5,
) -> None:
    """Simulate one trial of a scenario's bursts as received, one per sample of its flight,
    and write it as a SigMF recording (cf32_le samples; the track, the schedule and the truth
    in the emitterbench extension)."""
    import numpy as np

    from scenarios.catalog import get_scenario
    from scenarios.limits import check_limit
    from scenarios.recording import write_recording
    from scenarios.signal import BurstPlan, received_bursts
    from scenarios.simulate import noise_free

    flags = {
        "waveform": "--waveform",
        "burst_s": "--burst-s",
        "sample_rate_hz": "--sample-rate-hz",
        "chip_rate_hz": "--chip-rate-hz",
        "cn0_dbhz": "--cn0-dbhz",
        "output": "--output",
    }
    chosen = get_scenario(scenario)
    with flags_for(flags):
        plan = BurstPlan(
            waveform=waveform,
            burst_s=burst_s,
            sample_rate_hz=sample_rate_hz,
            cn0_dbhz=cn0_dbhz,
            chip_rate_hz=chip_rate_hz if waveform == "bpsk" else None,
        )
        n_samples = chosen.flight.n_samples * plan.n_samples
        fix = "shorten --burst-s or lower --sample-rate-hz"
        check_limit(n_samples, "--burst-s", "IQ samples", IQ_SAMPLES, fix)
        received = received_bursts(chosen, plan, [seed])
        meta_path, data_path = write_recording(output, noise_free(chosen), plan, received)
    n_bursts = received.samples.shape[1]
    largest_hz = float(np.max(np.abs(burst_doppler_hz(noise_free(chosen)))))
    cycles = largest_hz * plan.burst_s
    unknown_offset = "carrier_offset_hz" in chosen.unknowns
    if plan.waveform == "bpsk" and unknown_offset and cycles > DOPPLER_CYCLES_PER_BURST:
        shorter_s = plan.burst_s * DOPPLER_CYCLES_PER_BURST / cycles
        typer.echo(
            f"warning: the Doppler turns {cycles:.3g} cycles over a burst and the carrier "
            f"offset is unknown: measure the recording with --doppler-search-hz "
            f"{rounded_up(SEARCH_MARGIN * largest_hz):g} (its largest |Doppler|, "
            f"{largest_hz:.4g} Hz, and a margin; MATH §20), or shorten --burst-s to "
            f"{rounded_down(shorter_s):.1g} s, or use --waveform cw",
            err=True,
        )
    megabytes = data_path.stat().st_size / 1e6
    typer.echo(
        f"wrote {meta_path} and {data_path}: {chosen.name}, {n_bursts} {plan.waveform} bursts "
        f"of {plan.n_samples} samples ({megabytes:.3g} MB), C/N0 {cn0_dbhz:g} dB-Hz, burst SNR "
        f"{10 * math.log10(plan.burst_snr):.1f} dB, seed {seed}"
    )


def rounded_up(value: float) -> float:
    """``value`` > 0 rounded up to two significant digits."""
    digit = 10.0 ** (math.floor(math.log10(value)) - 1)
    return math.ceil(value / digit) * digit


def rounded_down(value: float) -> float:
    """``value`` > 0 rounded down to one significant digit."""
    digit = 10.0 ** math.floor(math.log10(value))
    return math.floor(value / digit) * digit


def burst_doppler_hz(geometry: Any) -> Any:
    """The bursts' Doppler, carrier offset included (MATH §1, §15, §18), from the truth of a
    noise-free :class:`~scenarios.types.MeasurementSet`."""
    from scenarios.measurement_model import doppler_hz

    return doppler_hz(
        geometry.position_m,
        geometry.velocity_mps,
        geometry.truth_emitter_m,
        geometry.gamma_per_m,
        geometry.emitter_height_m,
        geometry.truth_carrier_offset_hz or 0.0,
    )


def measure_command(
    recording: Annotated[
        Path, typer.Argument(help="Recording REC.sigmf-meta (its samples in REC.sigmf-data).")
    ],
    output: Annotated[
        Path, typer.Option("--output", "-o", help="Measurement file to write (.json).")
    ],
    doppler_search_hz: DopplerSearchOption = None,
) -> None:
    """Measure every burst of a recording (its Doppler; its ToA for BPSK) with the front end,
    reading a block of bursts at a time, and write the measurement file estimate reads."""
    from scenarios.files import write_measurements

    if output.suffix.lower() != ".json":
        raise ValueError(f"--output: {output} must end in .json")
    data, line = measured_recording(recording, doppler_search_hz)
    with flags_for({"output": "--output"}):
        write_measurements(data, output)
    typer.echo(f"{line}; wrote {output}")
