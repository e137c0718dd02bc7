"""The forward model at a candidate (MATH §1, §8): how well a point reproduces data, whitened by
the data's σ's (:func:`data_misfit`, :func:`whitened_misfit`), and the Cramér-Rao bound the
noisy checks compare with (:func:`crlb_rmse_m`)."""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
from numpy.typing import NDArray

from scenarios import measurement_model as model
from scenarios.fisher import fisher_information, rmse_bound_m
from scenarios.types import MODALITIES, MeasurementSet

FloatArray = NDArray[np.float64]


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


def whitened_misfit(data: MeasurementSet, point_m: FloatArray, modalities: Iterable[str]) -> float:
    """``‖(h(s) − y)/σ‖``: the norm of the whitened residuals of ``data`` at ``point_m`` over
    ``modalities`` (those absent from ``data`` are skipped); how many σ the data are from what
    the point predicts. To first order, data that far from an emitter's noise-free values move
    the maximum likelihood at most ``whitened_misfit × √λ_max(J⁻¹)`` from it (MATH §8, §10)."""
    residual, _ = _whitened_model(data, point_m, tuple(modalities))
    return float(np.linalg.norm(residual))


def crlb_rmse_m(data: MeasurementSet, emitter_m: FloatArray, modalities: Iterable[str]) -> float:
    """``√trace(J⁻¹)`` (MATH §8) of ``data``'s samples and σ's over ``modalities`` (those absent
    from ``data`` are skipped); inf if ``J`` is singular. (:mod:`scenarios.fisher`'s bound, the
    one :mod:`comparison.crlb` reports.)"""
    chosen = set(modalities)
    used = tuple(m for m in MODALITIES if m in chosen and m in data.modalities)
    if not used:
        return math.inf
    bound = float(rmse_bound_m(fisher_information(data, emitter_m, used)))
    return bound if math.isfinite(bound) else math.inf
