"""Validation of a closed-form CLS against its SDP relaxation (MATH §5, §11)."""

from __future__ import annotations

import base64
import json
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import pytest
from typer.testing import CliRunner

import estimators.sdp.sdp_solvers as sdp_solvers
from comparison.cli import app
from comparison.crosscheck import (
    FAMILIES,
    instance_seeds,
    make_instance,
    point_set_distance,
    replay,
    replay_with_verdict,
    run_validation,
    validate_instance,
)
from estimators.base import finalize_estimate, require_modalities
from estimators.closed_form.cls import Cls, ClsAsPrinted, ClsPaper
from estimators.closed_form.gtrs import solve_gtrs
from estimators.registry import make_estimator


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
        xy = solution.points[:, :2]
        if solution.hard_case:
            M, q = problem.A.T @ problem.A, problem.A.T @ problem.b
            lam = 1e-9 * np.trace(M)
            r = np.linalg.solve(M + lam * np.diag([1.0, 1.0, 0.0]), q + lam * np.array([0, 0, 0.5]))
            xy = r[None, :2]
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
    result = run_validation(instances=40, families=FAMILIES, seed=11, estimator=name)
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
