"""Validation of a closed-form CLS against its SDP relaxation (MATH §5, §11)."""

from __future__ import annotations

import base64
import json
from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np
import pytest
from typer.testing import CliRunner

import estimators.sdp.sdp_solvers as sdp_solvers
from comparison.cli import app
from comparison.crosscheck import (
    FAMILIES,
    FAMILY_DIMENSION,
    check_candidates,
    compare_solutions,
    instance_seeds,
    make_instance,
    point_set_distance,
    replay,
    replay_with_verdict,
    run_validation,
    validate_instance,
)
from estimators.base import Estimate, finalize_estimate, require_modalities
from estimators.closed_form.cls import Cls, ClsAsPrinted, ClsPaper
from estimators.closed_form.gtrs import solve_gtrs
from estimators.registry import make_estimator
from estimators.sdp.sdp_cls import solve_sdp_relaxation

FAMILIES_2D = tuple(family for family in FAMILIES if FAMILY_DIMENSION[family] == 2)
FAMILIES_3D = ("climb-height", "level-height")


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
    assert calls[-1] == (24, 24, "level-height") and len(calls) == 24
    payload = json.loads((tmp_path / "validate.json").read_text())
    assert payload["ok"] is True and payload["seed"] == 3
    assert set(payload["families"]) == set(FAMILIES)
    for name, summary in payload["families"].items():
        assert summary["dimension"] == (3 if name in FAMILIES_3D else 2)
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
    assert "| family | d | n |" in markdown and "| level-height | 3 | 4 |" in markdown
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
    def broken_solve(*args, **kwargs):
        raise RuntimeError("numerical trouble")

    monkeypatch.setattr(sdp_solvers, "run_clarabel", broken_solve)
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
    result = run_validation(instances=1000, families=FAMILIES_2D, seed=0, out_dir=tmp_path)
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


# --------------------------------------------------------------------------------------------
# another closed form: run_validation(estimator=...) and `emitterbench validate --estimator`
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class MidpointCls(Cls):
    """Wrong on purpose: λ → 0⁺ in the hard case, the midpoint of the mirror pair (MATH §5)."""

    name: ClassVar[str] = "midpoint-cls"

    def estimate(self, data, *, rng=None):
        require_modalities(self, data)
        problem = self.constrained_ls(data)
        solution = solve_gtrs(problem.A, problem.b)
        d = problem.dimension
        xy = solution.points[:, :d]
        if solution.hard_case:
            M, q = problem.A.T @ problem.A, problem.A.T @ problem.b
            lam = 1e-9 * np.trace(M)
            D, g = np.diag([1.0] * d + [0.0]), np.eye(d + 1)[d] * 0.5
            xy = np.linalg.solve(M + lam * D, q + lam * g)[None, :d]
        points = problem.to_world(xy)
        used = data.select_frames(self.frames)
        return finalize_estimate(self.name, points, problem.cost(points), used, rng=rng)


@dataclass(frozen=True, kw_only=True)
class RowsThatRaise(Cls):
    name: ClassVar[str] = "rows-that-raise"

    def constrained_ls(self, data):
        raise RuntimeError("no rows today")


@dataclass(frozen=True, kw_only=True)
class RowsOfTheWrongType(Cls):
    name: ClassVar[str] = "rows-of-the-wrong-type"

    def constrained_ls(self, data):
        return super().constrained_ls(data).A


@pytest.mark.parametrize("name", ["cls-paper", "cls"])
def test_the_builtin_closed_forms_pass_on_every_family(name):
    """Every candidate attains the exact optimum of the estimator's own rows; both mirror
    minimisers in the hard case; the SDP value equals the optimum; every status optimal."""
    result = run_validation(instances=40, families=FAMILIES_2D, seed=11, estimator=name)
    assert result.ok, [(r.family, r.seed, r.reasons) for r in result.disagreements]
    assert result.estimator == name and result.estimator_args == f"--estimator {name}"
    for summary in result.families.values():
        assert summary.n == 40 and summary.statuses == {"optimal": 40}
        assert summary.n_sdp_failed == summary.n_estimator_failed == 0
        assert summary.max_estimator_rel_cost_gap <= 1e-9
        assert summary.max_estimator_distance_rel <= 1e-9
        assert summary.n_estimator_missing == summary.n_estimator_extra == 0
        assert summary.max_rel_objective_gap <= 1e-6
    for r in result.results:
        assert r.candidates.n_minimisers == (2 if r.hard_case else 1)
        assert r.candidates.n_candidates >= r.candidates.n_minimisers
    hard = {family: summary.n_hard for family, summary in result.families.items()}
    assert hard["straight"] > 30 and hard["paper"] > 30
    if name == "cls-paper":  # frames="last": one straight frame of the turn, mostly hard
        assert hard["turn"] > 30 and hard["turn-weighted"] > 30
    else:  # every frame: two headings, a unique minimiser
        assert hard["turn"] == hard["turn-weighted"] == 0


def test_an_estimator_with_the_familys_rows_reproduces_the_builtin_check():
    """On ``turn`` the family's rows are cls(weighting="none")'s: the SDP side is identical."""
    builtin = run_validation(instances=6, families=["turn"], seed=2)
    mine = run_validation(instances=6, families=["turn"], seed=2, estimator=Cls(weighting="none"))
    assert mine.ok and builtin.ok
    assert mine.estimator_args == "--estimator cls --option weighting=none"
    for ours, theirs in zip(mine.results, builtin.results, strict=True):
        assert ours.seed == theirs.seed
        assert ours.closed_form_value == theirs.closed_form_value
        assert ours.hard_case == theirs.hard_case and ours.status == theirs.status
        assert ours.rel_objective_gap == pytest.approx(theirs.rel_objective_gap, abs=1e-12)
        assert theirs.candidates is None and ours.candidates.n_missing == 0


def test_cls_exposes_the_rows_its_estimate_minimises():
    instance = make_instance("turn-weighted", instance_seeds(4, "turn-weighted", 1)[0])
    for estimator in (Cls(), Cls(frames="last"), ClsPaper(), ClsAsPrinted()):
        problem = estimator.constrained_ls(instance.data)
        estimate = estimator.estimate(instance.data)
        optimum = solve_gtrs(problem.A, problem.b).costs.min()
        np.testing.assert_allclose(problem.cost(estimate.candidates_m), optimum, rtol=1e-10)
        assert not problem.A.flags.writeable


def test_the_midpoint_closed_form_is_caught_with_a_replay_seed(tmp_path):
    """λ → 0⁺ returns the midpoint of the mirror pair in the hard case: every hard instance
    disagrees (both minimisers missing, the midpoint far above the optimum), the others agree,
    and the listed seed replays the disagreement."""
    result = run_validation(
        instances=12,
        families=("straight", "paper"),
        seed=0,
        out_dir=tmp_path,
        estimator=MidpointCls(),
    )
    assert not result.ok
    hard = [r for r in result.results if r.hard_case]
    assert len(hard) >= 18  # one straight frame: mostly the hard case
    assert {(r.family, r.seed) for r in result.disagreements} == {(r.family, r.seed) for r in hard}
    for r in result.results:
        if r.hard_case:
            assert r.candidates.n_missing == 2 and r.candidates.n_extra >= 1
            assert r.candidates.max_rel_cost_gap > 0.1  # the tolerance is 1e-6
            assert "not among the candidates" in "; ".join(r.reasons)
        else:
            assert r.agrees and r.candidates.max_rel_cost_gap <= 1e-9
    for summary in result.families.values():
        assert summary.n_disagreements == summary.n_hard > 0
        assert summary.n_estimator_missing == 2 * summary.n_hard
    payload = json.loads((tmp_path / "validate.json").read_text())
    assert payload["estimator"]["name"] == "midpoint-cls"
    entry = payload["disagreements"][0]
    assert entry["replay"] == (
        f"emitterbench validate --replay {entry['seed']} --families {entry['family']} "
        "--estimator tests.comparison.test_validate:MidpointCls"
    )
    assert entry["candidates"]["n_missing"] == 2
    assert "## The estimator's candidates" in (tmp_path / "validate.md").read_text()
    # the seed reproduces it; the correct closed form agrees on the same instance
    text, agrees = replay_with_verdict(entry["seed"], entry["family"], estimator=MidpointCls())
    assert not agrees and "DISAGREE" in text and "hard case True" in text
    assert "estimate (midpoint-cls)" in text and "missing 2" in text
    text, agrees = replay_with_verdict(entry["seed"], entry["family"], estimator="cls")
    assert agrees and text.rstrip().endswith("AGREE")


def test_an_estimator_without_the_protocol_is_refused_naming_the_method():
    for estimator in ("lls-toa", make_estimator("ml")):
        with pytest.raises(ValueError, match=r"^estimator: .*add a method constrained_ls\(self"):
            run_validation(instances=1, families=["straight"], estimator=estimator)
    with pytest.raises(ValueError, match=r"^estimator: .*constrained_ls\(self"):
        replay(1, "straight", estimator="lls-rss")
    with pytest.raises(ValueError, match=r"^estimator: .* returned ndarray; return an estim"):
        run_validation(instances=1, families=["straight"], estimator=RowsOfTheWrongType())


def test_an_estimator_that_raises_is_a_listed_disagreement():
    result = run_validation(instances=2, families=["turn"], seed=0, estimator=RowsThatRaise())
    assert not result.ok and len(result.disagreements) == 2
    assert result.families["turn"].n_estimator_failed == 2
    assert all(r.status == "not_run" and not r.sdp_failed for r in result.results)
    assert result.disagreements[0].reasons == ("estimator raised RuntimeError: no rows today",)


def test_a_failing_sdp_is_reported_as_sdp_failed_not_agreement(monkeypatch):
    def broken_solve(*args, **kwargs):
        raise RuntimeError("numerical trouble")

    monkeypatch.setattr(sdp_solvers, "run_clarabel", broken_solve)
    result = run_validation(instances=2, families=["paper"], seed=0, estimator="cls")
    summary = result.families["paper"]
    assert not result.ok and summary.n_sdp_failed == summary.n_disagreements == 2
    assert summary.n_estimator_missing == summary.n_estimator_extra == 0  # the candidates are fine
    assert all(r.reasons[0].startswith("SDP failed: solver status") for r in result.disagreements)


def test_cli_validate_exit_codes(tmp_path):
    runner = CliRunner()
    ok = runner.invoke(
        app,
        [
            "validate",
            "--estimator",
            "cls-paper",
            "--option",
            "frames=all",
            "--instances",
            "3",
            "-o",
            str(tmp_path / "paper"),
        ],
    )
    assert ok.exit_code == 0, ok.output
    assert "estimator cls-paper" in ok.stdout and ok.stdout.count("missing 0  extra 0") == 4
    payload = json.loads((tmp_path / "paper" / "validate.json").read_text())
    assert (
        payload["ok"]
        and payload["estimator"]["args"] == "--estimator cls-paper --option frames=all"
    )

    wrong = "tests.comparison.test_validate:MidpointCls"
    caught = runner.invoke(
        app,
        [
            "validate",
            "--estimator",
            wrong,
            "--families",
            "straight",
            "--instances",
            "4",
            "-o",
            str(tmp_path / "wrong"),
        ],
    )
    assert caught.exit_code == 1, caught.output
    replay_lines = [line for line in caught.stderr.splitlines() if "replay with" in line]
    assert replay_lines and "instance(s) disagree" in caught.stderr
    command = replay_lines[0].split("replay with emitterbench ")[1].split()
    assert command[:2] == ["validate", "--replay"] and command[-2:] == ["--estimator", wrong]
    replayed = runner.invoke(app, command)
    assert replayed.exit_code == 1 and "DISAGREE" in replayed.stdout
    seed = command[2]
    fine = runner.invoke(app, ["validate", "--replay", seed, "--families", "straight", "-e", "cls"])
    assert fine.exit_code == 0 and fine.stdout.rstrip().endswith("AGREE")

    refused = runner.invoke(app, ["validate", "--estimator", "lls-toa", "-o", str(tmp_path / "x")])
    assert refused.exit_code == 2 and refused.stdout == ""
    (line,) = refused.stderr.strip().splitlines()
    assert line.startswith("error: estimator: 'lls-toa'") and "constrained_ls(self, data)" in line
    assert not (tmp_path / "x").exists()


# --------------------------------------------------------------------------------------------
# the emitter's height unknown: the 3-D families (MATH §5 in three coordinates, §7, §11)
# --------------------------------------------------------------------------------------------

EXACT_RTOL = 1e-8
"""Noise-free minimisers against the truth, of the length scale: the rows are exact to
rounding, and the worst of 30 instances per family is 1.3e-10 (the families reach ranges of
some hundred track lengths, whose conditioning costs those digits)."""

VALUE_ATOL = 1e-12
"""Times ``‖b‖²``: a noise-free optimum is zero to rounding, so the SDP value is held to the
rounding of the cost summed over the rows (the relative gap has no scale there)."""


def world_minimisers(instance):
    """The closed form's minimisers of the instance's rows in world metres, and the solution."""
    closed = solve_gtrs(instance.A, instance.b)
    return instance.problem.to_world(closed.points[:, :3]), closed


@pytest.mark.parametrize("family", FAMILIES_3D)
def test_a_noise_free_3d_instance_has_the_emitter_as_its_minimiser(family):
    """Noise-free, the closed form's minimisers are the emitter (climb-height) or the emitter
    and its reflection through the flight plane (level-height), and the SDP relaxation's value
    is the optimum, zero to rounding."""
    for seed in instance_seeds(21, family, 8):
        instance = make_instance(family, seed, exact=True)
        assert instance.dimension == 3 and instance.A.shape[1] == 4
        points, closed = world_minimisers(instance)
        truth = instance.data.truth_emitter_m
        height = instance.data.position_m[:, 2].max()
        expected = [truth] if family == "climb-height" else [truth, truth * [1, 1, -1]]
        if family == "level-height":
            expected[1] = expected[1] + [0.0, 0.0, 2.0 * height]
        assert closed.hard_case == (family == "level-height")
        assert len(points) == len(expected)
        order = np.argsort(points[:, 2])
        np.testing.assert_allclose(
            points[order], np.array(expected), rtol=0.0, atol=EXACT_RTOL * instance.length_scale_m
        )
        sdp = solve_sdp_relaxation(instance.A, instance.b)
        assert sdp.status == "optimal" and sdp.lift.shape == (5, 5)
        bb = instance.b @ instance.b
        assert abs(sdp.value - closed.costs.min()) <= VALUE_ATOL * bb


def test_the_3d_families_have_the_advertised_structure():
    """climb-height: rank 4, one minimiser, the emitter below the UAV's lowest sample;
    level-height: every sample at one height, rank 3 (the null vector ``(0, 0, 1, 2h)``)."""
    for family in FAMILIES_3D:
        for seed in instance_seeds(5, family, 6):
            instance = make_instance(family, seed)
            data = instance.data
            assert data.truth_emitter_m.shape == (3,) and "emitter_height_m" in data.unknowns
            assert len(np.unique(data.frame)) == 3 and instance.rows == "weighted"
            assert 0.0 <= data.truth_emitter_m[2] < data.position_m[:, 2].min()
            closed = solve_gtrs(instance.A, instance.b)
            if family == "climb-height":
                assert closed.rank == 4 and not closed.hard_case
                assert np.ptp(data.position_m[:, 2]) > 0.0
            else:
                assert closed.rank == 3
                assert np.ptp(data.position_m[:, 2]) == 0.0
                h = data.position_m[0, 2] / instance.length_scale_m
                null = np.array([0.0, 0.0, 1.0, 2.0 * h])
                assert np.linalg.norm(instance.A @ null) <= 1e-12 * np.linalg.norm(instance.A)


def test_level_height_returns_both_minimisers_and_the_sdp_its_pair():
    """Noisy level flights: in the hard case the closed form returns two minimisers at equal
    cost, mirror images through the flight plane ``z = h`` (one (x, y), heights summing to
    2h), and the SDP's rank-two lift recovers the same pair (MATH §5, §11)."""
    hard = 0
    for seed in instance_seeds(9, "level-height", 12):
        instance = make_instance("level-height", seed)
        result, closed, sdp = validate_instance(instance)
        assert result.agrees, result.reasons
        if not closed.hard_case:
            continue
        hard += 1
        points = instance.problem.to_world(closed.points[:, :3])
        height = instance.data.position_m[0, 2]
        assert len(points) == 2
        np.testing.assert_allclose(points[0, :2], points[1, :2], rtol=0.0, atol=1e-9 * height)
        assert points[:, 2].sum() == pytest.approx(2.0 * height, rel=1e-9)
        np.testing.assert_allclose(closed.costs[0], closed.costs[1], rtol=1e-12)
        assert sdp.rank == 2 and len(sdp.points) == 2
        assert result.pair_distance_rel <= 1e-3
    assert hard >= 9


@pytest.mark.parametrize("family", FAMILIES_3D)
def test_cls_in_3d_is_validated_on_its_own_rows(family):
    """``--estimator cls`` on data of unknown height: rows over (x, y, z, ‖s‖²); every
    candidate attains their optimum; of a level flight's pair the reflection above the UAV is
    not due (the mirror rule drops it, MATH §7) and the emitter's side is returned."""
    result = run_validation(instances=10, families=[family], seed=4, estimator="cls")
    assert result.ok, [(r.family, r.seed, r.reasons) for r in result.disagreements]
    summary = result.families[family]
    assert summary.dimension == 3 and summary.n_estimator_missing == 0
    assert summary.max_estimator_rel_cost_gap <= 1e-9
    for r in result.results:
        check = r.candidates
        assert check.n_candidates == 1
        assert check.n_above_uav == (1 if r.hard_case else 0)
        assert check.n_minimisers == (2 if r.hard_case else 1)
    if family == "level-height":
        assert summary.n_hard >= 8


@dataclass(frozen=True, kw_only=True)
class AboveTheUavCls(Cls):
    """Wrong on purpose: returns the highest of the closed form's minimisers (in a level
    flight's hard case, the reflection above the UAV)."""

    name: ClassVar[str] = "above-the-uav-cls"

    def estimate(self, data, *, rng=None):
        problem = self.constrained_ls(data)
        points = problem.to_world(solve_gtrs(problem.A, problem.b).points[:, :3])
        highest = points[np.argmax(points[:, 2])][None]
        return Estimate(
            estimator=self.name, position_m=highest[0], candidates_m=highest, ambiguous=False
        )


def test_returning_the_reflection_above_the_uav_is_caught():
    """The reflection costs the optimum, but the minimiser below the UAV is due and missing."""
    instance = make_instance("level-height", instance_seeds(9, "level-height", 1)[0])
    problem = Cls().constrained_ls(instance.data)
    closed = solve_gtrs(problem.A, problem.b)
    assert closed.hard_case
    ceiling = float(instance.data.position_m[:, 2].max())
    wrong = AboveTheUavCls().estimate(instance.data)
    check, reasons = check_candidates(problem, wrong, closed, ceiling_m=ceiling)
    assert check.n_missing == 1 and check.n_above_uav == 1 and check.n_extra == 0
    assert check.max_rel_cost_gap <= 1e-9  # it is a global minimiser, just not the due one
    assert "the minimiser below the UAV must be returned" in reasons[0]
    with pytest.raises(ValueError, match=r"^ceiling_m: "):
        check_candidates(problem, wrong, closed)
    right = Cls().estimate(instance.data)
    check, reasons = check_candidates(problem, right, closed, ceiling_m=ceiling)
    assert reasons == () and check.n_missing == 0 and check.n_candidates == 1


def test_a_closed_form_that_misses_a_mirror_minimiser_disagrees_in_height():
    """A closed form that returns one point of a level flight's pair (the one the SDP does not
    rank first) differs from the SDP's argmin in the height alone: the check compares all three
    coordinates, and says that both recovered points attain the optimum."""
    instance = make_instance("level-height", instance_seeds(9, "level-height", 1)[0])
    _, closed, sdp = validate_instance(instance)
    assert closed.hard_case and len(sdp.points) == 2
    other = int(np.argmax(np.linalg.norm(closed.points - sdp.points[np.argmin(sdp.costs)], axis=1)))
    keep = slice(other, other + 1)
    one = replace(closed, points=closed.points[keep], costs=closed.costs[keep], hard_case=False)
    result = compare_solutions(
        instance, one, sdp, closed_form_time_s=0.0, rtol_objective=1e-6, rtol_argmin=1e-3
    )
    separation = abs(closed.points[0, 2] - closed.points[1, 2])
    assert result.argmin_distance_rel == pytest.approx(separation, rel=1e-6)
    assert separation > 1e-2 and not result.agrees
    assert "both points recovered from the SDP's lift attain" in result.reasons[1]


def test_an_estimator_that_takes_the_height_as_known_skips_the_3d_families(tmp_path):
    """``cls-paper`` refuses data of unknown height: the 3-D families are not run (the result,
    validate.json and validate.md say why), and asking for them alone is refused in one line."""
    result = run_validation(
        instances=1,
        families=("turn", *FAMILIES_3D),
        seed=0,
        estimator="cls-paper",
        out_dir=tmp_path,
    )
    assert result.ok and set(result.families) == {"turn"}
    assert set(result.skipped) == set(FAMILIES_3D)
    payload = json.loads((tmp_path / "validate.json").read_text())
    assert set(payload["skipped_families"]) == set(FAMILIES_3D)
    assert (
        "Not run: climb-height, level-height: cls-paper takes the emitter's height as known"
        in (tmp_path / "validate.md").read_text()
    )
    with pytest.raises(ValueError, match=r"^families: climb-height, level-height leave the emit"):
        run_validation(instances=1, families=FAMILIES_3D, estimator="cls-paper")
    assert "skipped_families" not in run_validation(instances=1, families=["turn"]).to_dict()


def test_no_answer_agrees_when_every_minimiser_is_above_the_uav():
    """A unique minimiser above the UAV is not due: a failed estimate (the mirror rule leaves
    nothing) agrees, and with the UAV above it the same failure is a missing minimiser."""
    instance = make_instance("climb-height", instance_seeds(9, "climb-height", 1)[0])
    problem = Cls().constrained_ls(instance.data)
    closed = solve_gtrs(problem.A, problem.b)
    (height,) = problem.to_world(closed.points[:, :3])[:, 2]
    failed = Estimate.failed("cls", "no candidate below the UAV", dimension=3)
    check, reasons = check_candidates(problem, failed, closed, ceiling_m=height - 1.0)
    assert reasons == () and check.n_above_uav == 1 and check.n_missing == 0
    assert np.isnan(check.max_distance_m)
    check, reasons = check_candidates(problem, failed, closed, ceiling_m=height + 1.0)
    assert reasons == ("estimate failed: no candidate below the UAV",) and check.n_missing == 1
