"""A run's tie-breaking generators, made when read (:class:`estimators.batch.TrialGenerators`).

A batch gets the same draws from them as from a list of the same generators made in advance,
and the generators of the trials that draw nothing are never made.
"""

from __future__ import annotations

import numpy as np
import pytest

from estimators.batch import TrialGenerators, check_rngs
from estimators.closed_form.cls import Cls
from estimators.ml.ml import MaximumLikelihood
from scenarios.catalog import get_scenario
from scenarios.simulate import simulate_trials, trial_seeds


def seeded(i: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(5, spawn_key=(i,)))


def counted(n: int) -> tuple[TrialGenerators, list[int]]:
    """Generators of ``n`` trials, and the list of the trials whose generator was made."""
    made: list[int] = []

    def make(i: int) -> np.random.Generator:
        made.append(i)
        return seeded(i)

    return TrialGenerators(n, make), made


def test_each_generator_is_made_once_when_first_read_and_draws_as_one_made_in_advance():
    lazy, made = counted(6)
    assert len(lazy) == 6 and made == []
    draws = [lazy[i].integers(1000) for i in (4, 1, 4, -1)]
    assert made == [4, 1, 5]  # 4 once; -1 is trial 5
    assert lazy[4] is lazy[-2]
    reference = [seeded(i) for i in range(6)]
    assert draws == [reference[i].integers(1000) for i in (4, 1, 4, 5)]


def test_it_is_indexed_sliced_and_iterated_as_a_list():
    lazy, made = counted(4)
    assert [g is lazy[i] for i, g in enumerate(lazy)] == [True] * 4
    assert lazy[1:3] == [lazy[1], lazy[2]]
    assert sorted(set(made)) == [0, 1, 2, 3] and len(made) == 4
    with pytest.raises(IndexError):
        lazy[4]
    with pytest.raises(IndexError):
        lazy[-5]


def test_check_rngs_takes_it_as_it_is_and_refuses_the_wrong_length():
    lazy, made = counted(3)
    assert check_rngs(lazy, 3) is lazy and made == []
    with pytest.raises(ValueError, match="one generator per trial"):
        check_rngs(lazy, 4)


@pytest.mark.bits("the same estimator on the same arrays, generators made in advance or when read")
@pytest.mark.parametrize(
    ("estimator", "scenario"),
    [(Cls(), "paper-1m"), (Cls(), "paper-1m-turn"), (MaximumLikelihood(), "paper-1m")],
)
def test_a_batch_draws_the_same_ties_and_makes_only_the_generators_it_reads(estimator, scenario):
    """On one straight frame every trial is a mirror tie (a draw); after the turn none is."""
    batch = simulate_trials(get_scenario(scenario), snr_db=10.0, seeds=trial_seeds(11, 40))
    lazy, made = counted(40)
    columns = estimator.estimate_columns(batch, rngs=lazy)
    listed = estimator.estimate_columns(batch, rngs=[seeded(i) for i in range(40)])
    np.testing.assert_array_equal(columns.position_m, listed.position_m)
    np.testing.assert_array_equal(columns.candidates_m, listed.candidates_m)
    drawn = int(np.sum(columns.ambiguous & columns.success))
    assert len(made) == len(set(made)) == drawn
    assert drawn == (40 if scenario == "paper-1m" else 0)
