"""The closed form with an unknown carrier offset (MATH §15): δ projected out of the GTRS."""

from __future__ import annotations

import numpy as np
import pytest

from estimators.closed_form.cls_batch import system_of_trial
from estimators.closed_form.cls_rows import project_out
from estimators.closed_form.gtrs import solve_gtrs
from estimators.registry import make_estimator
from scenarios import get_scenario
from scenarios.fisher import fisher_information, rmse_bound_m
from scenarios.simulate import noise_free, simulate, simulate_trials, trial_seeds
from tests.estimators.batch_support import path_problems

OFFSET = ("carrier_offset_hz",)


def with_offset(name: str, offset_hz: float = 800.0):
    return get_scenario(name).replace(unknowns=OFFSET, carrier_offset_hz=offset_hz)


@pytest.mark.parametrize("name", ["turn", "paper-1m-turn"])
@pytest.mark.parametrize("offset_hz", [-1200.0, 0.0, 800.0])
def test_noise_free_two_headings_give_the_emitter_and_the_offset(name, offset_hz) -> None:
    scenario = with_offset(name, offset_hz)
    estimate = make_estimator("cls").estimate(noise_free(scenario))
    assert estimate.success and not estimate.ambiguous
    np.testing.assert_allclose(estimate.candidates_m, [scenario.emitter_m], atol=1e-6)
    assert estimate.diagnostics["carrier_offset_hz"] == pytest.approx(offset_hz, abs=1e-6)


def test_noise_free_straight_frame_gives_the_mirror_pair_and_the_offset() -> None:
    scenario = with_offset("paper-1m")
    estimate = make_estimator("cls").estimate(noise_free(scenario))
    assert estimate.ambiguous
    np.testing.assert_allclose(
        sorted(estimate.candidates_m.tolist()), [[35.0, -15.0], [35.0, 15.0]], atol=1e-6
    )
    assert estimate.diagnostics["carrier_offset_hz"] == pytest.approx(800.0, abs=1e-6)


def test_the_projected_gtrs_minimises_the_cost_over_the_offset_too() -> None:
    """Brute force: on a grid of δ, the GTRS of the full rows with δ moved to the right-hand
    side never goes below the projected optimum, and reaches it at the returned δ."""
    data = simulate(with_offset("turn"), snr_db=10.0, seed=4)
    estimate = make_estimator("cls").estimate(data)
    A, b, column, _ = system_of_trial(data, "weighted", last_stage=True)
    assert column is not None and np.any(column != 0.0)
    projected = solve_gtrs(*project_out(A, b, column))
    best = projected.costs.min()
    grid = estimate.diagnostics["carrier_offset_hz"] + np.linspace(-2.0, 2.0, 81)
    costs = [solve_gtrs(A, b - delta * column).costs.min() for delta in grid]
    assert min(costs) >= best * (1 - 1e-9)
    assert costs[40] == pytest.approx(best, rel=1e-9)


def test_cls_attains_the_nuisance_bound_on_a_turn() -> None:
    scenario = with_offset("turn")
    batch = simulate_trials(scenario, snr_db=20.0, seeds=trial_seeds(11, 1000))
    cls = make_estimator("cls")
    errors = np.array(
        [cls.estimate(batch.trial(i)).position_m - scenario.emitter_m for i in range(1000)]
    )
    rmse = np.sqrt(np.mean(np.sum(errors**2, axis=1)))
    bound = float(rmse_bound_m(fisher_information(batch.geometry, scenario.emitter_m)))
    known = float(rmse_bound_m(fisher_information(batch.geometry, scenario.emitter_m, unknowns=())))
    assert bound > 1.4 * known  # the offset has a price here
    assert rmse / bound == pytest.approx(1.0, abs=0.07)  # 1000 trials: ±4.5% at 2σ


@pytest.mark.paths
def test_the_batch_path_gives_what_one_trial_at_a_time_gives() -> None:
    batch = simulate_trials(with_offset("paper-1m-turn"), snr_db=0.0, seeds=trial_seeds(2, 20))
    cls = make_estimator("cls")
    rngs = [np.random.default_rng(i) for i in range(20)]
    columns = cls.estimate_batch(batch, rngs=rngs)
    for i, estimate in enumerate(columns):
        single = cls.estimate(batch.trial(i), rng=np.random.default_rng(i))
        assert path_problems(cls, batch.trial(i), single, estimate) == [], i


@pytest.mark.parametrize("name", ["cls-paper", "cls-as-printed", "lls-toa", "sdp-cls"])
def test_estimators_that_take_the_carrier_as_known_refuse_and_name_one_that_can(name) -> None:
    data = noise_free(with_offset("turn"))
    estimator = make_estimator(name)
    if "doppler" not in estimator.requires and "doppler" not in getattr(
        estimator.capabilities(), "modalities", ()
    ):
        assert estimator.estimate(data).success  # ToA only: the offset does not concern it
        return
    with pytest.raises(ValueError, match=r"unknowns: .*carrier offset unknown.*use 'cls'"):
        estimator.estimate(data)
    # ignoring the unknown on purpose shows the bias that costs
    biased = estimator.estimate(data.assuming_known())
    assert np.linalg.norm(biased.position_m - [35.0, 15.0]) > 1.0


@pytest.mark.parametrize("name", ["turn-noncooperative", "beacon-pass"])
@pytest.mark.parametrize(
    "unknowns", [("emission_time_s",), ("carrier_offset_hz", "emission_time_s")], ids=str
)
@pytest.mark.parametrize("offset_method", ["relaxed", "profile"])
def test_noise_free_pseudo_ranges_give_the_emitter_and_both_offsets(
    name, unknowns, offset_method
) -> None:
    scenario = get_scenario(name).replace(unknowns=unknowns)
    estimate = make_estimator("cls", offset_method=offset_method).estimate(noise_free(scenario))
    assert estimate.success and not estimate.ambiguous
    np.testing.assert_allclose(estimate.candidates_m, [scenario.emitter_m], atol=1e-6)
    assert estimate.diagnostics["emission_time_s"] == pytest.approx(
        scenario.emission_time_s, abs=1e-13
    )
    if "carrier_offset_hz" in unknowns:
        assert estimate.diagnostics["carrier_offset_hz"] == pytest.approx(
            scenario.carrier_offset_hz, abs=1e-6
        )


def test_pseudo_ranges_on_a_straight_frame_give_the_mirror_pair() -> None:
    scenario = get_scenario("paper-1m").replace(unknowns=("emission_time_s",), emission_time_s=3e-4)
    estimate = make_estimator("cls").estimate(noise_free(scenario))
    assert estimate.ambiguous
    np.testing.assert_allclose(
        sorted(estimate.candidates_m.tolist()), [[35.0, -15.0], [35.0, 15.0]], atol=1e-6
    )


def test_the_relaxed_closed_form_pays_its_price_and_the_profile_does_not() -> None:
    """Both offsets unknown on the beacon pass at 20 dB, 300 trials: the relaxed closed form
    sits near 1.6 √CRLB (MATH §15, the relaxation w = ρ_j δ), the profile attains the bound."""
    scenario = get_scenario("beacon-pass")
    batch = simulate_trials(scenario, snr_db=20.0, seeds=trial_seeds(3, 300))
    bound = float(rmse_bound_m(fisher_information(batch.geometry, scenario.emitter_m)))
    efficiency = {}
    for method in ("relaxed", "profile"):
        cls = make_estimator("cls", offset_method=method)
        errors = [cls.estimate(batch.trial(i)).position_m - scenario.emitter_m for i in range(300)]
        efficiency[method] = np.sqrt(np.mean(np.sum(np.square(errors), axis=1))) / bound
    assert efficiency["relaxed"] == pytest.approx(1.6, abs=0.15)
    assert efficiency["profile"] == pytest.approx(1.0, abs=0.1)  # 300 trials: ±8% at 2σ


def test_an_unweighted_cls_refuses_an_unknown_emission_time() -> None:
    data = noise_free(get_scenario("turn-noncooperative"))
    with pytest.raises(ValueError, match=r"emission time unknown.*'cls'"):
        make_estimator("cls", weighting="none").estimate(data)
