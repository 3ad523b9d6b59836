"""The ablation of Contact Edit's Fig. 11, the benchmark problem, and their commands."""

import numpy as np
import pytest

from contact_edit_addon.commands import cli
from geodesics.benchmark import Row
from solver import benchmark


@pytest.fixture(scope="module")
def rows():
    table = benchmark.ablation()
    return {(r.scene.split(",")[0], r.variant.split(" (")[0]): r for r in table}


@pytest.mark.parametrize("scene", ["human hand", "tentacle"])
def test_without_the_distance_term_the_hand_does_not_reach(rows, scene):
    assert rows[scene, "full"].distance < 2.0  # % of the hand's length
    assert rows[scene, "no distance"].distance > 30.0


@pytest.mark.parametrize("scene", ["human hand", "tentacle"])
def test_without_the_prior_joints_deviate_far_more(rows, scene):
    full, free = rows[scene, "full"], rows[scene, "no prior"]
    assert free.deviation > 1.8 * full.deviation
    assert free.max_deviation > 1.5 * full.max_deviation
    assert free.penetration > full.penetration  # contorted fingers push into the object


def test_without_the_normal_term_the_geometry_is_neglected(rows):
    full, blind = rows["human hand", "full"], rows["human hand", "no normal"]
    assert blind.normal > full.normal  # the surfaces are less opposed
    assert blind.penetration > 1.5 * full.penetration


def test_ablation_table_and_command(rows, monkeypatch, capsys):
    text = benchmark.format_ablation(list(rows.values()))
    assert "no prior (λp = 0)" in text and "% length" in text and len(text.splitlines()) == 2 + 8
    monkeypatch.setattr(benchmark, "ablation", lambda progress=None: list(rows.values()))
    assert cli.main(["ablation"]) == 0
    assert text in capsys.readouterr().out


def test_bench_solver_command_prints_the_rows(monkeypatch, capsys):
    fake = [Row("contact IK (slsqp): human hand", 0.5, 15.0, "same solve, forward finite differences", "30x")]
    monkeypatch.setattr(benchmark, "run", lambda repeat, progress=None: fake)
    assert cli.main(["bench", "solver", "--repeat", "2"]) == 0
    out = capsys.readouterr().out
    assert "contact IK (slsqp): human hand" in out and "forward finite differences" in out


def test_benchmark_problem_is_the_issue_s():
    hand, points, targets, normals, truth = benchmark.bench_problem()
    assert hand.kind == "human" and hand.rig.n_dofs == 54
    assert len(points) == 2000 == len(targets) == len(normals)
    assert np.linalg.norm(truth[:3]) == pytest.approx(0.02)
    posed, _ = hand.posed_points(truth, points)
    assert np.allclose(posed, targets)
