"""Validation of the closed-form CLS against its SDP relaxation (MATH §5, §11)."""

from __future__ import annotations

import base64
import json

import cvxpy as cp
import numpy as np
import pytest

from comparison.validate import (
    FAMILIES,
    instance_seeds,
    make_instance,
    point_set_distance,
    replay,
    run_validation,
    validate_instance,
)
from estimators.gtrs import solve_gtrs


@pytest.mark.parametrize("family", FAMILIES)
def test_sdp_optimum_equals_closed_form_on_each_family(family):
    """A dozen seeded instances per family: gap <= 1e-6, argmin or pair within 1e-3 of scale."""
    for seed in instance_seeds(123, family, 12):
        result, closed, sdp = validate_instance(make_instance(family, seed))
        assert sdp.status == "optimal"
        assert result.rel_objective_gap <= 1e-6
        assert abs(sdp.value - closed.costs.min()) <= 1e-6 * closed.costs.min()
        if closed.hard_case:
            assert result.pair_distance_rel <= 1e-3 and np.isnan(result.argmin_distance_rel)
        else:
            assert result.argmin_distance_rel <= 1e-3 and np.isnan(result.pair_distance_rel)
        assert result.agrees


def test_families_have_the_advertised_structure():
    straight = [make_instance("straight", s) for s in instance_seeds(5, "straight", 6)]
    turn = [make_instance("turn", s) for s in instance_seeds(5, "turn", 6)]
    weighted = [make_instance("turn-weighted", s) for s in instance_seeds(5, "turn-weighted", 6)]
    paper = [make_instance("paper", s) for s in instance_seeds(5, "paper", 6)]
    assert all(len(np.unique(i.data.frame)) == 1 for i in straight + paper)
    assert all(len(np.unique(i.data.frame)) == 2 for i in turn + weighted)
    assert {i.rows for i in straight + weighted + paper} == {"weighted"}
    assert {i.rows for i in turn} == {"per-sample"}
    # a single straight frame has rank 2 (MATH §5); a turn has full rank
    assert all(solve_gtrs(i.A, i.b).rank == 2 for i in straight + paper)
    assert all(solve_gtrs(i.A, i.b).rank == 3 for i in turn + weighted)
    # the paper family keeps the paper geometry (MATH §14)
    for instance in paper:
        np.testing.assert_allclose(instance.data.truth_emitter_m, [35.0, 15.0])
        assert instance.parameters["scenario"] in ("paper-1m", "paper-10m")


def test_instances_are_reproducible_from_their_own_seed():
    seeds = instance_seeds(7, "turn", 5)
    assert instance_seeds(7, "turn", 3) == seeds[:3]
    assert instance_seeds(7, "straight", 5) != seeds
    assert instance_seeds(8, "turn", 5) != seeds
    first, again = make_instance("turn", seeds[2]), make_instance("turn", seeds[2])
    np.testing.assert_array_equal(first.A, again.A)
    np.testing.assert_array_equal(first.b, again.b)
    assert not np.array_equal(make_instance("turn", seeds[3]).b, first.b)


def test_point_set_distance_is_hausdorff():
    pair = np.array([[0.0, 1.0], [0.0, -1.0]])
    assert point_set_distance(pair, pair[::-1]) == 0.0
    assert point_set_distance(pair, pair[:1]) == pytest.approx(2.0)
    assert point_set_distance(pair, np.empty((0, 2))) == np.inf


def test_run_writes_json_markdown_and_html(tmp_path):
    calls = []
    result = run_validation(
        instances=4,
        families=FAMILIES,
        seed=3,
        out_dir=tmp_path,
        progress=lambda done, total, family: calls.append((done, total, family)),
    )
    assert result.ok
    assert calls[-1] == (16, 16, "paper") and len(calls) == 16
    payload = json.loads((tmp_path / "validate.json").read_text())
    assert payload["ok"] is True and payload["seed"] == 3
    assert set(payload["families"]) == set(FAMILIES)
    for summary in payload["families"].values():
        assert summary["n"] == 4
        assert summary["statuses"] == {"optimal": 4}
        assert summary["max_rel_objective_gap"] <= 1e-6
        assert summary["median_sdp_time_s"] > 0.0
    straight = payload["families"]["straight"]
    assert straight["n_hard"] + straight["n_unique"] == 4
    assert straight["max_candidate_pair_distance_m"] is not None
    assert payload["disagreements"] == []
    markdown = (tmp_path / "validate.md").read_text()
    assert "**PASS**" in markdown and "straight" in markdown
    html = (tmp_path / "validate.html").read_text()
    encoded = html.split("data:image/png;base64,")[1].split("'")[0]
    assert base64.b64decode(encoded)[:8] == b"\x89PNG\r\n\x1a\n"
    assert (tmp_path / "validate_gaps.png").read_bytes()[:4] == b"\x89PNG"


def test_disagreements_are_listed_with_their_seed(tmp_path):
    """An impossible tolerance makes every instance disagree; each is listed for replay."""
    result = run_validation(
        instances=3, families=["turn"], seed=1, out_dir=tmp_path, rtol_objective=1e-300
    )
    assert not result.ok
    nonzero = [r for r in result.results if r.rel_objective_gap > 1e-300]
    assert len(result.disagreements) == len(nonzero) > 0
    payload = json.loads((tmp_path / "validate.json").read_text())
    assert payload["ok"] is False
    listed = {d["seed"] for d in payload["disagreements"]}
    assert listed == {r.seed for r in nonzero}
    entry = payload["disagreements"][0]
    assert entry["replay"] == f"emitterbench validate --replay {entry['seed']} --families turn"
    assert "relative objective gap" in entry["reasons"][0]
    assert str(entry["seed"]) in (tmp_path / "validate.md").read_text()


def test_a_failing_solver_is_a_disagreement(monkeypatch):
    def broken_solve(self, *args, **kwargs):
        raise cp.error.SolverError("numerical trouble")

    monkeypatch.setattr(cp.Problem, "solve", broken_solve)
    result = run_validation(instances=2, families=["straight"], seed=0)
    assert not result.ok
    assert result.families["straight"].statuses == {"solver_error": 2}
    assert all("solver status solver_error" in r.reasons[0] for r in result.disagreements)


def test_replay_describes_one_instance():
    seed = instance_seeds(0, "straight", 1)[0]
    text = replay(seed, "straight")
    assert f"instance straight seed {seed}" in text
    assert "status optimal" in text and "eigenvalues of Z" in text
    assert "lambda*" in text and text.rstrip().endswith("AGREE")


@pytest.mark.parametrize(
    ("options", "field"),
    [
        ({"instances": 0}, "instances"),
        ({"instances": 2, "families": ["spiral"]}, "families"),
        ({"instances": 2, "families": []}, "families"),
        ({"instances": 2, "rtol_objective": 0.0}, "rtol_objective"),
        ({"instances": 2, "rtol_argmin": float("nan")}, "rtol_argmin"),
    ],
)
def test_bad_options_raise_value_error_naming_the_field(options, field):
    with pytest.raises(ValueError, match=rf"^{field}: "):
        run_validation(**options)


@pytest.mark.slow
def test_acceptance_one_thousand_instances_per_family(tmp_path):
    """>= 1000 seeded instances per family: every objective gap <= 1e-6, every unique argmin and
    every hard-case mirror pair within 1e-3 of the length scale, every status optimal."""
    result = run_validation(instances=1000, families=FAMILIES, seed=0, out_dir=tmp_path)
    for family, summary in result.families.items():
        print(
            f"{family}: n={summary.n} hard={summary.n_hard} "
            f"gap={summary.max_rel_objective_gap:.2e} "
            f"argmin={summary.max_argmin_distance_m:.2e} m "
            f"({summary.max_argmin_distance_rel:.2e}) "
            f"pair={summary.max_candidate_pair_distance_m:.2e} m "
            f"({summary.max_candidate_pair_distance_rel:.2e}) "
            f"sdp={summary.median_sdp_time_s * 1e3:.2f} ms "
            f"cf={summary.median_closed_form_time_s * 1e3:.3f} ms"
        )
        assert summary.n == 1000
        assert summary.statuses == {"optimal": 1000}
        assert summary.max_rel_objective_gap <= 1e-6
        if summary.n_unique:
            assert summary.max_argmin_distance_rel <= 1e-3
        if summary.n_hard:
            assert summary.max_candidate_pair_distance_rel <= 1e-3
    assert result.families["straight"].n_hard > 500
    assert result.families["paper"].n_hard > 500
    assert result.families["turn"].n_hard == result.families["turn-weighted"].n_hard == 0
    assert result.ok, [(r.family, r.seed, r.reasons) for r in result.disagreements]
    for summary in result.families.values():
        # the inequality relaxation: tight whenever λ* >= 0, strictly below whenever λ* < 0
        print(
            f"{summary.family}: λ*>=0 {summary.n_multiplier_nonnegative} "
            f"(tight {summary.n_inequality_tight_when_nonnegative}), λ*<0 "
            f"{summary.n_multiplier_negative} (not tight {summary.n_inequality_loose_when_negative}"
            f", min gap {summary.min_inequality_gap_when_negative:.2e})"
        )
        assert summary.n_inequality_tight_when_nonnegative == summary.n_multiplier_nonnegative
        # the gap vanishes as λ* → 0⁻, so a few barely negative multipliers fall within 1e-6
        assert summary.n_inequality_loose_when_negative >= 0.99 * summary.n_multiplier_negative
        if summary.n_multiplier_negative:
            assert summary.min_inequality_gap_when_negative > 1e-9  # strictly below, always
    assert result.families["turn"].n_multiplier_negative > 100


def test_inequality_relaxation_is_tight_exactly_when_the_multiplier_is_nonnegative(tmp_path):
    """MATH §11: r_z >= ‖y‖² is tight when λ* >= 0 and strictly loose when λ* < 0."""
    result = run_validation(instances=16, families=("turn", "straight"), seed=3, out_dir=tmp_path)
    turn, straight = result.families["turn"], result.families["straight"]
    assert turn.n_multiplier_negative > 0 and turn.n_multiplier_nonnegative > 0
    assert turn.n_inequality_tight_when_nonnegative == turn.n_multiplier_nonnegative
    assert turn.n_inequality_loose_when_negative == turn.n_multiplier_negative
    assert turn.min_inequality_gap_when_negative > 1e-6
    assert turn.max_inequality_gap_when_nonnegative <= 1e-6
    # one straight frame: λ* = −μ₁ = 0 (the hard case), and the inequality is tight
    assert straight.n_multiplier_negative == 0
    assert straight.n_inequality_tight_when_nonnegative == straight.n
    assert "## The inequality relaxation" in (tmp_path / "validate.md").read_text()
    assert "The inequality relaxation</h2>" in (tmp_path / "validate.html").read_text()
