"""The goodness of fit at an estimate (MATH §17): its value, its distribution, its paths.

χ² of the whitened residuals at the answer, over the samples and modalities the estimator uses,
with ``dof = n − 2 − (unknown nuisance parameters)``. Without noise it is zero up to the
estimate's own distance from the truth; at the truth it is χ²(n) (χ²(n − n_ν) with the
nuisance profiled); at the maximum-likelihood answer about χ²(n − p); an outlier or a wrong
speed of light makes it enormous, and the fit is rejected.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy import stats

from estimators import make_estimator
from estimators.base import Estimate, capabilities_of
from estimators.goodness_of_fit import (
    FIT_TEST_LEVEL,
    chi2_quantile,
    fit_chi_square,
    fit_of,
    fit_p_value,
    fit_rejected,
    fit_warning,
    with_fit,
)
from estimators.ml.ml import MaximumLikelihood
from scenarios import get_scenario, noise_free
from scenarios.fisher import fisher_information
from scenarios.simulate import simulate, simulate_trials, trial_seeds
from scenarios.types import MEASURED_FIELD, MeasurementSet
from tests.paths import EPS, SAFETY

# estimator, scenario it handles, measurements it uses per sample, nuisance parameters
BUILT_INS = [
    ("cls", "turn", 2, 0),
    ("cls-paper", "turn", 2, 0),
    ("lls-toa", "turn", 1, 0),
    ("lls-rss", "turn", 1, 0),
    ("sdp-cls", "turn", 2, 0),
    ("ekf", "turn", 2, 0),
    ("gtsam-smoother", "turn", 2, 0),
    ("ml", "turn", 2, 0),
    ("cls", "turn-noncooperative", 2, 2),
    ("ekf", "beacon-pass", 2, 2),
    ("gtsam-smoother", "beacon-pass", 2, 2),
    ("ml", "beacon-pass", 2, 2),
]


def whitened_size(data: MeasurementSet, modalities) -> float:
    """``‖z/σ‖``: the size of the whitened measurements, whose rounding χ² inherits."""
    return math.sqrt(
        sum(
            float(np.sum((getattr(data, MEASURED_FIELD[m]) / data.noise.for_modality(m)) ** 2))
            for m in modalities
        )
    )


@pytest.mark.parametrize(("name", "scenario", "per_sample", "nuisance"), BUILT_INS)
def test_noise_free_data_fit_to_the_estimates_own_error(name, scenario, per_sample, nuisance):
    """χ² ≈ δᵀJδ for an answer δ from the truth (J the information, MATH §8): zero up to the
    estimate's own exactness, plus the rounding of residuals of size ‖z/σ‖; ``fit_dof`` is
    the measurements used minus (x, y) and the nuisance parameters."""
    s = get_scenario(scenario)
    data = noise_free(s, snr_db=20.0)
    estimator = make_estimator(name)
    estimate = estimator.estimate(data, rng=np.random.default_rng(0))
    assert estimate.success, estimate.message
    chi2 = estimate.diagnostics["fit_chi2"]
    used = data.select_frames(capabilities_of(estimator).frames)  # cls-paper: the last
    assert estimate.diagnostics["fit_dof"] == per_sample * used.n_samples - 2 - nuisance
    modalities = sorted(capabilities_of(estimator).modalities)
    information = fisher_information(data, s.emitter_m, "+".join(modalities))
    distance_m = float(np.min(np.linalg.norm(estimate.candidates_m - s.emitter_m, axis=1)))
    distance_m = max(distance_m, float(np.linalg.norm(estimate.position_m - s.emitter_m)))
    rounding = SAFETY * EPS * whitened_size(data, modalities)
    bound = 2.0 * np.linalg.eigvalsh(information)[-1] * distance_m**2 + rounding**2
    assert 0.0 <= chi2 <= bound
    assert fit_warning(estimate.diagnostics) is None


def test_the_paper_as_printed_does_not_fit_its_own_noise_free_data():
    """MATH §4: without the height term the answer is 37 m off (35, ±52.2): χ² shows it."""
    data = noise_free(get_scenario("paper-1m"), snr_db=20.0)
    estimate = make_estimator("cls-as-printed").estimate(data)
    assert estimate.success and fit_rejected(**fit_arguments(estimate.diagnostics))
    assert estimate.diagnostics["fit_chi2"] > 1e4


def fit_arguments(diagnostics) -> dict:
    return {"chi2_value": diagnostics["fit_chi2"], "dof": diagnostics["fit_dof"]}


@pytest.mark.parametrize(("scenario", "nuisance"), [("turn", 0), ("beacon-pass", 2)])
def test_at_the_truth_chi2_has_mean_n_and_variance_2n(scenario, nuisance):
    """At the true emitter the whitened residuals are n independent N(0, 1): χ²(n), mean n,
    variance 2n. With δ and b unknown each centred block loses one dimension: χ²(n − 2).
    Over T trials the mean's standard deviation is √(2n/T) and the sample variance's
    √((8n² + 48n)/T) (χ²(n) has fourth central moment 12n² + 48n); both within 4 of them."""
    s = get_scenario(scenario)
    trials = 4000
    batch = simulate_trials(s, snr_db=10.0, seeds=trial_seeds(21, trials))
    g = batch.geometry
    measured = {m: getattr(batch, MEASURED_FIELD[m]) for m in ("doppler", "toa")}
    chi2, dof = fit_chi_square(np.broadcast_to(s.emitter_m, (trials, 2)), g, measured)
    n = 2 * g.n_samples - nuisance  # the profiled χ² at the truth (no position fitted)
    assert dof == n - 2
    assert abs(chi2.mean() - n) <= 4.0 * math.sqrt(2.0 * n / trials)
    assert abs(chi2.var(ddof=1) - 2.0 * n) <= 4.0 * math.sqrt((8.0 * n**2 + 48.0 * n) / trials)
    # and the 1% test rejects about 1% of them: binomial, 4 standard deviations
    rate = fit_rejected(chi2, n).mean()
    assert abs(rate - 0.01) <= 4.0 * math.sqrt(0.01 * 0.99 / trials)


@pytest.mark.parametrize(("scenario", "trials"), [("turn", 1000), ("beacon-pass", 300)])
def test_at_the_ml_answer_chi2_has_mean_n_minus_p(scenario, trials):
    """ML minimises χ²: to first order the residual is w projected off the p columns of the
    Jacobian, χ²(n − p). Over T trials its mean is within 4 √(2(n − p)/T) of n − p, and the
    paired drop from the truth, χ²(truth) − χ²(ML) ≈ χ²(2) (the two position columns), has
    mean 2 within 4 √(4/T): the dof count is right to a fraction of one parameter."""
    s = get_scenario(scenario)
    batch = simulate_trials(s, snr_db=20.0, seeds=trial_seeds(33, trials))
    ml = MaximumLikelihood()
    if batch.geometry.unknowns:  # one trial at a time (MATH §15)
        estimates = [ml.estimate(batch.trial(i)) for i in range(trials)]
        assert all(e.success for e in estimates)
        chi2 = np.array([e.diagnostics["fit_chi2"] for e in estimates])
        dof = estimates[0].diagnostics["fit_dof"]
    else:
        columns = ml.estimate_columns(batch)
        assert columns.success.all()
        chi2, dof = columns.diagnostics["fit_chi2"], int(columns.diagnostics["fit_dof"][0])
    at_truth, _ = fit_of(ml, batch, np.broadcast_to(s.emitter_m, (trials, 2)))
    assert abs(chi2.mean() - dof) <= 4.0 * math.sqrt(2.0 * dof / trials)
    drop = at_truth - chi2
    assert drop.min() >= -1e-9 * at_truth.max()  # the minimum of χ² lies below the truth's
    assert abs(drop.mean() - 2.0) <= 4.0 * math.sqrt(4.0 / trials)


def spoilt(data: MeasurementSet, fault: str) -> MeasurementSet:
    if fault == "outlier":  # one ToA sample 10⁴ σ late
        toa = np.array(data.toa_s)
        toa[3] += 1e4 * data.noise.toa_s
        return dataclasses.replace(data, toa_s=toa)
    return dataclasses.replace(data, speed_of_light_mps=100.0 * data.speed_of_light_mps)


@pytest.mark.parametrize("fault", ["outlier", "light"])
@pytest.mark.parametrize("name", ["cls", "ml", "sdp-cls", "ekf", "gtsam-smoother", "lls-toa"])
def test_an_outlier_or_a_wrong_speed_of_light_is_rejected(name, fault):
    """The issue's cases: `cls` 254 m off and `ml` 6 km off reported success with nothing
    saying the data do not fit. Every success is now rejected at 1% (its clean twin is not)."""
    data = simulate(get_scenario("paper-1m-turn"), snr_db=20.0, seed=5)
    estimator = make_estimator(name)
    clean = estimator.estimate(data, rng=np.random.default_rng(0))
    assert clean.success and not fit_rejected(**fit_arguments(clean.diagnostics))
    estimate = estimator.estimate(spoilt(data, fault), rng=np.random.default_rng(0))
    if not estimate.success:  # a failure says so itself; it has no fit to report
        assert "fit_chi2" not in estimate.diagnostics
        return
    assert fit_rejected(**fit_arguments(estimate.diagnostics))
    threshold = stats.chi2.ppf(0.99, estimate.diagnostics["fit_dof"])
    assert estimate.diagnostics["fit_chi2"] > 100 * threshold
    assert fit_warning(estimate.diagnostics).startswith("the data do not fit the model")


def test_cls_and_ml_are_rejected_with_a_spoilt_sample_on_one_frame():
    data = spoilt(simulate(get_scenario("paper-1m"), snr_db=20.0, seed=5), "outlier")
    for name in ("cls", "ml"):
        estimate = make_estimator(name).estimate(data, rng=np.random.default_rng(0))
        assert estimate.success and fit_rejected(**fit_arguments(estimate.diagnostics))


@pytest.mark.bits("fit_of on the same positions and the same measurement arrays as the paths")
@pytest.mark.parametrize("name", ["cls", "cls-paper", "ml", "sdp-cls"])
def test_every_path_reports_the_statistic_at_its_own_position(name):
    """``estimate_columns``, ``estimate_batch`` and ``estimate`` each report χ² at the position
    they return (the paths' positions agree by tests/paths.py, so their χ² do)."""
    s = get_scenario("paper-1m-turn")
    batch = simulate_trials(s, snr_db=10.0, seeds=trial_seeds(3, 12))
    estimator = make_estimator(name)
    columns = estimator.estimate_columns(batch)
    chi2, dof = fit_of(estimator, batch, columns.position_m)
    assert np.array_equal(columns.diagnostics["fit_chi2"], chi2)
    used = batch.geometry.select_frames(capabilities_of(estimator).frames)
    assert (columns.diagnostics["fit_dof"] == dof).all() and dof == 2 * used.n_samples - 2
    for i, estimate in enumerate(estimator.estimate_batch(batch)):
        assert (
            estimate.diagnostics["fit_chi2"]
            == fit_of(estimator, batch.trial(i), estimate.position_m)[0]
        )
    one = estimator.estimate(batch.trial(0))
    assert one.diagnostics["fit_chi2"] == fit_of(estimator, batch.trial(0), one.position_m)[0]


def test_the_frames_and_modalities_used_are_the_estimators():
    """``frames="last"`` fits the last frame's samples; ``ml(use_rss=True)`` adds RSS;
    ``ml(use_toa=False)`` drops ToA; a failed estimate gets no fit."""
    data = simulate(get_scenario("paper-1m-turn"), snr_db=20.0, seed=2)
    last = make_estimator("cls", frames="last").estimate(data)
    assert last.diagnostics["fit_dof"] == 2 * 10 - 2  # 10 samples a frame
    with_rss = make_estimator("ml", use_rss=True).estimate(data)
    assert with_rss.diagnostics["fit_dof"] == 3 * 100 - 2
    beacon = simulate(get_scenario("beacon-pass-doppler"), snr_db=20.0, seed=2)
    doppler = make_estimator("ml", use_toa=False).estimate(beacon)
    assert doppler.success and "emission_time_s" in beacon.unknowns  # in no Doppler sample
    assert doppler.diagnostics["fit_dof"] == beacon.n_samples - 3  # (x, y) and the offset
    failed = Estimate.failed("cls", "no answer")
    assert with_fit(make_estimator("cls"), failed, data) is failed


def test_the_fit_test_is_scipys_chi_square_quantile_and_tail():
    """fit_rejected's limit and fit_p_value are χ²(ν)'s quantile and tail (scipy.stats.chi2),
    for every ν a run can hold; nothing judged where ν < 1 or χ² is not finite."""
    rng = np.random.default_rng(17)
    dof = rng.integers(-2, 400, 5000).astype(float)
    value = np.where(rng.random(5000) < 0.02, np.nan, rng.uniform(-5.0, 500.0, 5000))
    judged = np.isfinite(value) & (dof >= 1)
    limit = stats.chi2.ppf(1.0 - FIT_TEST_LEVEL, np.where(judged, dof, 1.0))
    np.testing.assert_array_equal(fit_rejected(value, dof), judged & (value > limit))
    for v, d in zip(value[:500], dof[:500], strict=True):
        expected = stats.chi2.sf(v, d) if d >= 1 and np.isfinite(v) else np.nan
        np.testing.assert_allclose(fit_p_value(v, int(d)), expected, rtol=1e-12)


def test_the_chi_square_quantile_is_scipys_to_the_bit():
    """chi2_quantile is scipy.stats.chi2.ppf (the same special.gammaincinv on the same arrays)
    over the quantiles and degrees of freedom of the fit test and the NEES bands; NaN for NaN
    degrees of freedom (an empty group's band)."""
    rng = np.random.default_rng(3)
    q = rng.uniform(1e-6, 1.0 - 1e-6, 5000)
    dof = np.concatenate([rng.integers(1, 100_000, 4999).astype(float), [np.nan]])
    np.testing.assert_array_equal(chi2_quantile(q, dof), stats.chi2.ppf(q, dof))
