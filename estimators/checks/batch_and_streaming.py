"""The checks of the optional capabilities: ``estimate_batch`` equals ``estimate`` per trial,
and a sequential estimator's ``init``/``update``/``estimate_state`` equal ``estimate`` and keep
states as values."""

from __future__ import annotations

from typing import Any

import numpy as np

from estimators.checks.reference_problems import (
    RNG_SEED,
    noisy_reference,
    reference_batch,
    reference_rng,
)
from estimators.checks.results import (
    check_failed,
    estimate_or_fail,
    result_differences,
    result_problems,
    streamed_estimate,
)
from estimators.checks.tolerances import agreement_tolerance_m


def check_batch_matches_single(estimator: Any) -> None:
    """``estimate_batch`` returns one estimate per trial, each equal (within the agreement
    tolerance) to ``estimate`` on that trial with the same ``rng``."""
    batch = reference_batch()
    rngs = [np.random.default_rng(RNG_SEED + i) for i in range(batch.n_trials)]
    results = list(estimator.estimate_batch(batch, rngs=rngs))
    if len(results) != batch.n_trials:
        check_failed(
            f"estimate_batch returned {len(results)} estimates for {batch.n_trials} trials"
        )
    for index, result in enumerate(results):
        problems = result_problems(result, estimator)
        if problems:
            check_failed(f"estimate_batch, trial {index}: {'; '.join(problems)}")
        single = estimate_or_fail(
            estimator,
            batch.trial(index),
            f"trial {index}",
            rng=np.random.default_rng(RNG_SEED + index),
        )
        differences = result_differences(result, single, atol_m=agreement_tolerance_m(estimator))
        if differences:
            check_failed(
                f"estimate_batch differs from estimate on trial {index}: "
                f"{'; '.join(differences)}; a trial's result may not depend on its batch"
            )


def check_streaming_matches_estimate(estimator: Any) -> None:
    """``init``, ``update`` per frame of ``iter_frames`` and ``estimate_state`` give
    ``estimate``'s answer (within the agreement tolerance), with and without a turn."""
    for scenario, frames in (("turn", None), ("paper-1m", 2)):
        data = noisy_reference(scenario, frames)
        what = f"noisy '{scenario}' data, {data.frames.size} frames"
        whole = estimate_or_fail(estimator, data, what, rng=reference_rng())
        streamed = streamed_estimate(
            estimator, noisy_reference(scenario, frames), rng=reference_rng()
        )
        problems = result_problems(streamed, estimator)
        if problems:
            check_failed(f"estimate_state on {what}: {'; '.join(problems)}")
        differences = result_differences(whole, streamed, atol_m=agreement_tolerance_m(estimator))
        if differences:
            check_failed(
                f"streaming differs from estimate on {what}: {'; '.join(differences)}; "
                "estimate(data) should equal init/update over data.iter_frames()/estimate_state"
            )


def check_sequential_update_is_pure(estimator: Any) -> None:
    """``update(state, frame)`` returns a new state and leaves ``state`` usable: updating one
    state twice gives the same estimate, and an old state still gives its old estimate."""
    frames = list(noisy_reference("turn").iter_frames())
    first = estimator.update(estimator.init(), frames[0])
    before = estimator.estimate_state(first, rng=reference_rng())
    second = estimator.update(first, frames[1])
    again = estimator.update(first, frames[1])
    for label, a, b in (
        (
            "the first state after a second update",
            before,
            estimator.estimate_state(first, rng=reference_rng()),
        ),
        (
            "two updates of the same state",
            estimator.estimate_state(second, rng=reference_rng()),
            estimator.estimate_state(again, rng=reference_rng()),
        ),
    ):
        differences = result_differences(a, b, atol_m=agreement_tolerance_m(estimator))
        if differences:
            check_failed(
                f"{label} changed the estimate: {'; '.join(differences)}; update must return "
                "a new state and never modify the one it is given (an optax-style pure pair)"
            )
