"""A retarget job (solver.retarget.job): its motion carried into the target's space exactly, its folder
named by its inputs, and run in a child process that reports progress, stops when asked (keeping its
frames, which the next run goes on from) and gives back the same result as running it here."""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from solver import SolverError
from solver.hands import make_hand
from solver.retarget import RetargetOptions, synthetic
from solver.retarget.annotate import default_annotation
from solver.retarget.job import ChildRun, RetargetJob, Stopped, in_space, run_folder, run_job

FRAMES = 12


@pytest.fixture(scope="module")
def motion():
    """Twelve frames of a short synthetic grasp of the mug, without its contacts (the job finds them)."""
    m = synthetic.generate("mug", frames=44, fps=30.0).select(range(16, 16 + FRAMES))
    return replace(m, object_contacts=None, hand_contacts=None, source_theta=None)


def _similarity(scale: float) -> np.ndarray:
    M = np.eye(4)
    M[:3, :3] = scale * Rotation.from_euler("xyz", [0.3, -0.2, 1.1]).as_matrix()
    M[:3, 3] = [0.4, -0.1, 0.25]
    return M


def _job(folder: Path, **changes) -> RetargetJob:
    job = RetargetJob(
        ("Hand", "Mug", "Alien"), tuple(range(1, FRAMES + 1)), make_hand("alien"), np.eye(4), None,
        RetargetOptions(refine=False, intersections=False), True, folder,
    )  # fmt: skip
    return replace(job, **changes)


def _wait(run: ChildRun) -> None:
    while not run.done:
        run.poll()
        time.sleep(0.05)


def test_in_space_carries_every_point_by_the_transform(motion):
    M = _similarity(0.8)
    moved, back = in_space(motion, M)
    assert back == pytest.approx(1.25, rel=1e-12)
    for f in (0, FRAMES - 1):
        pose = motion.object_poses[f]
        world = motion.object_mesh.vertices @ pose[:3, :3].T + pose[:3, 3]
        pose2 = moved.object_poses[f]
        there = moved.object_mesh.vertices @ pose2[:3, :3].T + pose2[:3, 3]
        np.testing.assert_allclose(there, world @ M[:3, :3].T + M[:3, 3], atol=1e-12)
        np.testing.assert_allclose(moved.hand_vertices[f], motion.hand_vertices[f] @ M[:3, :3].T + M[:3, 3])
        np.testing.assert_allclose(np.linalg.det(pose2[:3, :3]), 1.0)
    np.testing.assert_allclose(moved.hand_mesh.vertices, 0.8 * motion.hand_mesh.vertices)


def test_the_run_folder_follows_the_inputs(motion, tmp_path):
    annotation = default_annotation(make_hand("human"), make_hand("alien"))
    job = _job(tmp_path)
    first = run_folder(job, motion, annotation)
    assert first.parent == tmp_path and first.name.startswith("Alien-")
    assert run_folder(_job(tmp_path), motion, annotation) == first
    assert run_folder(_job(tmp_path, identity="read at frame 3"), motion, annotation) != first
    other = replace(job.options, root_pass=False)
    assert run_folder(_job(tmp_path, options=other), motion, annotation) != first
    moved, _ = in_space(motion, _similarity(1.0))
    assert run_folder(job, moved, annotation) != first


@pytest.mark.slow
def test_a_child_run_reports_stops_keeps_its_frames_and_matches_a_run_here(motion, tmp_path):
    job = _job(tmp_path)
    stopped = ChildRun(job, motion, workers=1)
    while stopped.poll()[0] != "full" or stopped.progress[1] < 3:  # three frames' full poses solved
        assert not stopped.done, stopped.outcome()
        time.sleep(0.05)
    stopped.stop()
    _wait(stopped)
    with pytest.raises(Stopped, match="frames solved so far are kept"):
        stopped.outcome()
    kept = {p: p.stat().st_mtime_ns for p in tmp_path.glob("*/frames/full/*.npz")}
    assert 3 <= len(kept) < FRAMES

    seen = []
    child = ChildRun(job, motion, workers=2)
    while not child.done:
        seen.append(child.poll())
        time.sleep(0.05)
    outcome = child.outcome()
    assert {p for p, t in kept.items() if p.stat().st_mtime_ns != t} == set()  # not solved again
    assert {stage for stage, _, _ in seen} >= {"contacts", "transfer", "full", "metrics"}
    assert outcome.result.theta.shape == (FRAMES, make_hand("alien").rig.n_dofs)
    assert outcome.summary().startswith(f"Retargeted {FRAMES} frames; contacts ")

    here = run_job(job, motion, workers=1)  # the same folder: every frame is read back, none solved
    np.testing.assert_array_equal(here.result.theta, outcome.result.theta)
    assert here.folder == outcome.folder


@pytest.mark.slow
def test_a_child_run_says_why_it_failed(motion, tmp_path):
    poses = motion.object_poses.copy()
    poses[:, :3, 3] += 5.0  # the mug 5 m away: the hand never touches it
    child = ChildRun(_job(tmp_path), replace(motion, object_poses=poses))
    _wait(child)
    with pytest.raises(SolverError, match=r"'Hand' never comes within .* of 'Mug' in frames 1-12"):
        child.outcome()
