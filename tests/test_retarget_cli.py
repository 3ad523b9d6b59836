"""`contact-edit synthesize` and `contact-edit retarget`: outputs, resume, refusal of bad input."""

import json
import os
import re
import signal
import subprocess
from pathlib import Path

import numpy as np
import pytest

from contact_edit_addon.commands.cli import main
from solver.hands import make_hand
from solver.retarget import KeyframeMotion, Motion
from solver.retarget.metrics import IntersectionMeter

from .blender import CONTACT_EDIT


@pytest.fixture(scope="module")
def motion_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("cli") / "grasp.npz"
    assert main(["synthesize", str(path), "--object", "sphere", "--frames", "44", "--density", "2"]) == 0
    return path


@pytest.fixture(scope="module")
def retargeted(motion_file):
    out = motion_file.parent / "alien"
    args = ["retarget", str(motion_file), "--target", "alien", "-o", str(out), "--workers", "1"]
    assert main([*args, "--no-refine", "--control", "8"]) == 0
    return out, args


def test_synthesize_writes_a_motion_with_ground_truth(motion_file):
    motion = Motion.load(motion_file)
    assert motion.n_frames == 44 and motion.fps == 120.0 and motion.source_kind == "human"
    assert motion.hand_contacts.count().max() > 0


def test_retarget_writes_every_output(retargeted, motion_file):
    out, _ = retargeted
    source = Motion.load(motion_file)
    result = Motion.load(out / "motion.npz")
    alien = make_hand("alien")
    assert result.n_frames == source.n_frames and result.source_kind == "alien"
    assert result.hand_mesh.topology_hash == alien.mesh.topology_hash
    np.testing.assert_array_equal(result.object_poses, source.object_poses)
    # The stored vertices are the alien posed by the stored DOF curves.
    np.testing.assert_allclose(
        result.hand_vertices[20], alien.posed_vertices(result.source_theta[20]), atol=1e-12
    )
    with np.load(out / "curves.npz") as curves:
        assert curves["theta"].shape == (44, alien.rig.n_dofs) and curves["control"].shape == (
            8,
            alien.rig.n_dofs,
        )
        contact = curves["contact_distance"]
        measured = {k: curves[f"{k}_percent"] for k in ("hand_object", "self_intersection", "table")}
    # The frames' intersections, measured as per-frame tasks, are those of the stored motion in order.
    meter = IntersectionMeter(alien.mesh, result.object_mesh, result.table, result.table_size)
    again = meter.motion(result.hand_vertices, result.object_poses)
    assert any(values.max() > 0 for values in measured.values())
    for name, values in measured.items():
        np.testing.assert_allclose(values, getattr(again, name), rtol=1e-12, atol=1e-15)
    assert next((out / "frames").glob("metrics-*/000043.npz")).is_file()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == 44 and summary["spline_control_points"] == 8
    assert summary["median_contact_distance_mm"] == pytest.approx(np.nanmedian(contact) * 1e3)
    assert (out / "annotation.json").is_file()
    # The authors' .kmexp holds the same motion: its joint values give back the final curves.
    exported = KeyframeMotion.load(out / "motion.kmexp")
    assert exported.framerate == 120 and exported.frames.tolist() == list(range(1, 45))
    theta = exported.theta(alien.rig)
    for f in (0, 20, 43):
        np.testing.assert_allclose(alien.posed_vertices(theta[f]), result.hand_vertices[f], atol=1e-12)
    np.testing.assert_allclose(exported.object_poses(), source.object_poses, atol=1e-12)
    assert (out / "metrics.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(list((out / "frames" / "full").glob("*.npz"))) == 44


def test_running_again_resumes_without_solving(retargeted):
    out, args = retargeted
    stored = {p: p.stat().st_mtime_ns for p in (out / "frames").rglob("*.npz")}
    (out / "frames" / "full" / "000007.npz").unlink()  # as if interrupted before frame 7 was written
    assert main([*args, "--no-refine", "--control", "8"]) == 0
    again = {p: p.stat().st_mtime_ns for p in (out / "frames").rglob("*.npz")}
    assert set(again) == set(stored)
    changed = [p.name for p in again if again[p] != stored.get(p)]
    assert changed == ["000007.npz"]  # only the missing frame was solved


def test_an_annotation_drawn_to_match_the_default_retargets_the_same(retargeted, tmp_path):
    """Issue 18: patches drawn on both hands to match the built-in annotation, saved and read by
    ``--annotation``, give the built-in annotation's retarget, to the bit."""
    from solver.retarget import annotate

    from .test_retarget_drawn import drawn_to_match

    out, args = retargeted
    human, alien = make_hand("human"), make_hand("alien")
    drawn_to_match(human, alien, annotate.default_annotation(human, alien)).save(tmp_path / "drawn.json")
    again = tmp_path / "drawn"
    args = [*args[: args.index("-o") + 1], str(again), *args[args.index("-o") + 2 :]]
    assert main([*args, "--annotation", str(tmp_path / "drawn.json"), "--no-refine", "--control", "8"]) == 0
    with np.load(out / "curves.npz") as default, np.load(again / "curves.npz") as drawn:
        np.testing.assert_array_equal(drawn["theta"], default["theta"])


def test_the_plot_gets_the_commands_title(retargeted, motion_file, monkeypatch):
    """metrics.png is drawn by save_result with the title the command gives it (a resumed run)."""
    pytest.importorskip("matplotlib")
    from solver.retarget import metrics

    out, args = retargeted
    plotted = {}

    def plot_metrics(path, fps, **kwargs):
        plotted.update(kwargs, path=path, fps=fps)
        return path

    monkeypatch.setattr(metrics, "plot_metrics", plot_metrics)
    assert main([*args, "--no-refine", "--control", "8"]) == 0
    assert plotted["title"] == f"{motion_file.name}: 44 frames onto alien (scale 1)"
    assert plotted["path"] == out / "metrics.png" and plotted["fps"] == 120.0
    assert len(plotted["contact_count"]) == 44


def test_weights_reach_the_solves(retargeted, capsys):
    out, args = retargeted
    stored = {p: p.stat().st_mtime_ns for p in (out / "frames").rglob("*.npz")}
    # The defaults spelled out are the same run: it resumes with nothing to solve.
    defaults = ["--weight", "m=1", "--weight", "c=1", "--weight", "j=10"]
    assert main([*args, "--no-refine", "--control", "8", *defaults]) == 0
    assert {p: p.stat().st_mtime_ns for p in (out / "frames").rglob("*.npz")} == stored
    # Another contact weight is another run: refused, nothing overwritten.
    assert main([*args, "--no-refine", "--control", "8", "--weight", "c=2"]) == 1
    assert "holds results of another run" in capsys.readouterr().err
    for bad, words in (
        ("q=1", "the weights are m, c"),
        ("c=-1", ">= 0"),
        ("c=x", "not a number"),
        ("j=inf", ">= 0"),
    ):
        with pytest.raises(SystemExit) as exit_:
            main([*args, "--weight", bad])
        assert exit_.value.code == 2 and words in capsys.readouterr().err


def test_bad_input_is_refused_with_a_message(retargeted, motion_file, tmp_path, capsys):
    _, args = retargeted
    # Another run's options into the same folder: refused, nothing overwritten.
    assert main([*args, "--no-refine", "--no-contacts"]) == 1
    assert "holds results of another run" in capsys.readouterr().err
    broken = tmp_path / "broken.npz"
    broken.write_bytes(motion_file.read_bytes()[:5000])
    assert main(["retarget", str(broken), "--target", "alien", "-o", str(tmp_path / "x")]) == 1
    assert "contact-edit retarget:" in capsys.readouterr().err
    assert main(["retarget", str(motion_file), "--target", "robot", "-o", str(tmp_path / "y")]) == 1
    assert "robot" in capsys.readouterr().err
    assert main(["synthesize", str(tmp_path / "m.npz"), "--frames", "3"]) == 1
    assert "frames" in capsys.readouterr().err


def test_baselines_reuse_our_solves_and_write_table_1(retargeted, capsys):
    """``--baselines`` on a finished run: our frames are read back, only the baselines are solved; Table 1
    measures every method's final curves as the retarget measures its own."""
    from solver.retarget import annotations as an
    from solver.retarget import baselines as bl
    from solver.retarget import frames as fr

    out, args = retargeted
    stored = {p: p.stat().st_mtime_ns for p in (out / "frames").rglob("*.npz")}
    assert main([*args, "--no-refine", "--control", "8", "--baselines"]) == 0
    assert "Keyvector" in capsys.readouterr().out
    again = {p: p.stat().st_mtime_ns for p in (out / "frames").rglob("*.npz")}
    assert all(again[p] == t for p, t in stored.items())  # nothing of ours solved again
    assert {p.parent.name for p in set(again) - set(stored)} == {"keypoint", "keyvector"}
    summary = json.loads((out / "summary.json").read_text())
    table = summary["table1"]
    assert list(table) == ["Keypoint", "Keyvector", "Ours"]
    with np.load(out / "curves.npz") as curves:
        ours = curves["contact_distance"]
        methods = {"Keypoint": curves["keypoint_theta"], "Keyvector": curves["keyvector_theta"]}
    assert table["Ours"]["contact_median_cm"] == pytest.approx(100 * np.nanmedian(ours), rel=1e-12)
    # Both baselines are given the same root (our root pass), fitted alike.
    np.testing.assert_allclose(methods["Keypoint"][:, :6], methods["Keyvector"][:, :6], rtol=0, atol=1e-12)
    # Their rows against the baselines module's own per-frame measure of the stored curves.
    motion = Motion.load(out / "motion.npz")
    source = Motion.load(args[1])
    annotation = an.HandPairAnnotation.load(out / "annotation.json")
    tasks = fr.build_tasks(
        source, fr.HandSpec("alien"), annotation,
        hand_contacts=motion.hand_contacts, object_contacts=motion.object_contacts,
    )  # fmt: skip
    for method, theta in methods.items():
        contact, marker = bl.frame_distances(tasks, theta)
        assert table[method]["marker_median_cm"] == pytest.approx(100 * np.median(marker), rel=1e-9)
        assert table[method]["contact_median_cm"] == pytest.approx(100 * np.nanmedian(contact), rel=1e-9)
        assert table[method]["contact_frames"] == np.isfinite(contact).sum()
    text = (out / "table1.txt").read_text()
    assert [line.split()[0] for line in text.splitlines()[3:6]] == ["Keypoint", "Keyvector", "Ours"]
    assert "Refinement (§3.4.3) was skipped" in text and "Splines of 8 control points" in text


def terminated_retarget(motion_file, out: Path, group: bool) -> str:
    """``contact-edit retarget`` with two workers, in a real process, sent SIGTERM once it is solving full
    poses (``group``: to its whole process group, as ``timeout`` does, workers included); its stderr."""
    args = ["retarget", str(motion_file), "--target", "alien", "-o", str(out), "--workers", "2"]
    args += ["--no-refine", "--control", "8", "--no-plot"]
    root = str(Path(__file__).resolve().parents[1])  # this checkout's code, not an installed copy's
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")]))}
    process = subprocess.Popen(
        [*CONTACT_EDIT, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
        start_new_session=group,
    )  # fmt: skip
    try:
        seen = []
        for line in process.stderr:  # plain progress lines (not a terminal): wait for full-pose frames
            seen.append(line)
            if re.match(r"  full +[1-9]\d*/44 ", line):
                break
        else:
            pytest.fail(f"the retarget ended before solving full poses: {''.join(seen)}")
        if group:
            os.killpg(process.pid, signal.SIGTERM)
        else:
            process.send_signal(signal.SIGTERM)
        assert process.wait(timeout=60) == 128 + signal.SIGTERM  # before: killed (-15), or hung
        err = "".join(seen) + process.stderr.read()
    finally:
        if process.poll() is None:
            if group:
                os.killpg(process.pid, signal.SIGKILL)  # its workers too
            process.kill()
            process.wait()
        process.stdout.close()
        process.stderr.close()
    assert "leaked semaphore" not in err and "Traceback" not in err, err
    assert err.splitlines()[-1] == (
        "contact-edit retarget: interrupted; run the same command again to resume "
        f"(solved frames are kept in {out / 'frames'})"
    )
    return args


def test_sigterm_ends_a_retarget_as_ctrl_c_does_and_the_same_command_resumes(motion_file, tmp_path, capsys):
    """Issue 39: SIGTERM (``kill``, a scheduler's time limit) killed a retarget outright: the resource
    tracker reported its worker processes' semaphores leaked and nothing said what was kept. Now it ends
    as Ctrl-C does: the workers finish their frames and are joined, one line says how to resume, exit
    status 143 (128 + 15); the same command then solves only the rest."""
    out = tmp_path / "out"
    args = terminated_retarget(motion_file, out, group=False)
    kept = {p: p.stat().st_mtime_ns for p in (out / "frames" / "full").glob("*.npz")}
    assert 0 < len(kept) < 44 and not (out / "summary.json").exists()
    assert main(args) == 0  # the same command: it resumes
    first_full = next(line for line in capsys.readouterr().err.splitlines() if line.startswith("  full "))
    assert first_full.startswith(f"  full      {len(kept)}/44 ")  # the kept frames count as done
    assert {p: p.stat().st_mtime_ns for p in kept} == kept  # and are not solved again
    assert len(list((out / "frames" / "full").glob("*.npz"))) == 44 and (out / "summary.json").is_file()


def test_sigterm_to_the_whole_process_group_ends_a_retarget_the_same_way(motion_file, tmp_path):
    """``timeout`` and service managers signal the process group, the workers too: they used to die
    mid-frame and the command hung at exit on the frames still queued for them."""
    out = tmp_path / "out"
    terminated_retarget(motion_file, out, group=True)
    assert 0 < len(list((out / "frames" / "full").glob("*.npz"))) < 44
