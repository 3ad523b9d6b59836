"""How the command line ends: one line for bad input (exit 1), a traceback only with --debug, a clean
Ctrl-C (exit 130) that says how to go on, and the retarget's warnings never silent."""

import importlib.util
import os
from types import SimpleNamespace

import numpy as np
import pytest

from contact_edit_addon.commands.cli import main


def one_line(text: str) -> str:
    lines = text.splitlines()
    assert len(lines) == 1, text
    assert "Traceback" not in text
    return lines[0]


def test_a_motion_of_random_bytes_is_one_line_naming_the_file(tmp_path, capsys):
    motion = tmp_path / "motion.npz"
    motion.write_bytes(np.random.default_rng(0).bytes(4096))
    out = tmp_path / "out"
    assert main(["retarget", str(motion), "--target", "alien", "-o", str(out)]) == 1
    captured = capsys.readouterr()
    line = one_line(captured.err)
    assert line.startswith("contact-edit retarget: ") and str(motion) in line and "not a motion file" in line
    assert captured.out == "" and not out.exists()  # nothing written
    # --debug, before or after the command: the same line, after the traceback.
    for args in (["--debug", "retarget"], ["retarget", "--debug"]):
        assert main([*args, str(motion), "--target", "alien", "-o", str(out)]) == 1
        err = capsys.readouterr().err
        assert err.startswith("Traceback (most recent call last):") and "MotionError" in err
        assert err.splitlines()[-1] == line
    assert not out.exists()


def test_outputs_that_cannot_be_written_are_refused_before_the_work(tmp_path, capsys, monkeypatch):
    from solver.retarget import synthetic

    def generate(*args, **kwargs):
        raise AssertionError("the motion was generated before the output was checked")

    monkeypatch.setattr(synthetic, "generate", generate)
    assert main(["synthesize", str(tmp_path / "no" / "m.npz")]) == 1
    assert "no such folder for the output" in one_line(capsys.readouterr().err)
    assert main(["synthesize", str(tmp_path)]) == 1
    assert (
        one_line(capsys.readouterr().err)
        == f"contact-edit synthesize: {tmp_path}: a folder; name the file to write"
    )
    (tmp_path / "file").write_text("x")
    assert main(["retarget", str(tmp_path / "m.npz"), "--target", "alien", "-o", str(tmp_path / "file")]) == 1
    assert "not a folder" in one_line(capsys.readouterr().err)
    assert main(["retarget", str(tmp_path / "m.npz"), "--target", "alien", "-o", str(tmp_path / "out")]) == 1
    assert one_line(capsys.readouterr().err).endswith("m.npz: no such file")


def test_an_unexpected_error_is_one_line_with_a_hint_and_debug_shows_its_traceback(
    tmp_path, capsys, monkeypatch
):
    from solver.retarget import synthetic

    def generate(*args, **kwargs):
        return 1 / 0

    monkeypatch.setattr(synthetic, "generate", generate)
    path = str(tmp_path / "m.npz")
    assert main(["synthesize", path]) == 1
    line = one_line(capsys.readouterr().err)
    assert line.startswith("contact-edit synthesize: ZeroDivisionError: division by zero")
    assert "--debug" in line
    assert main(["--debug", "synthesize", path]) == 1
    err = capsys.readouterr().err
    assert "Traceback (most recent call last):" in err and "return 1 / 0" in err
    assert err.splitlines()[-1] == line


def interrupt(*args, **kwargs):
    raise KeyboardInterrupt


def fake_motion(monkeypatch, frames=44):
    """Motion.load and the default annotation, without reading or building anything."""
    from solver.retarget import annotate
    from solver.retarget.motion import Motion

    motion = SimpleNamespace(n_frames=frames, source_kind="human", source_scale=1.0, fps=120.0)
    monkeypatch.setattr(Motion, "load", staticmethod(lambda path: motion))
    monkeypatch.setattr(annotate, "default_annotation", lambda source, target: None)
    return motion


def test_ctrl_c_in_a_retarget_says_how_to_resume(tmp_path, capsys, monkeypatch):
    from solver.retarget import pipeline

    fake_motion(monkeypatch)
    monkeypatch.setattr(pipeline, "retarget", interrupt)
    out = tmp_path / "out"
    assert main(["retarget", "grasp.npz", "--target", "alien", "-o", str(out)]) == 130
    line = one_line(capsys.readouterr().err)
    assert line == (
        "contact-edit retarget: interrupted; run the same command again to resume "
        f"(solved frames are kept in {out / 'frames'})"
    )


def test_ctrl_c_elsewhere_ends_with_one_line_and_status_130(tmp_path, capsys, monkeypatch):
    from solver.retarget import benchmark, synthetic

    monkeypatch.setattr(synthetic, "generate", interrupt)
    assert main(["synthesize", str(tmp_path / "m.npz")]) == 130
    assert one_line(capsys.readouterr().err) == "contact-edit synthesize: interrupted"
    assert not (tmp_path / "m.npz").exists()
    # The retarget benchmark works in temporary folders: it says there is nothing to resume.
    monkeypatch.setattr(benchmark, "run", interrupt)
    assert main(["bench", "retarget"]) == 130
    line = one_line(capsys.readouterr().err)
    assert line.startswith("contact-edit bench retarget: interrupted;") and "nothing is kept" in line
    # With --debug, the traceback too.
    assert main(["--debug", "synthesize", str(tmp_path / "m.npz")]) == 130
    err = capsys.readouterr().err
    assert "Traceback" in err and "KeyboardInterrupt" in err
    assert err.splitlines()[-1] == "contact-edit synthesize: interrupted"


def test_sigterm_ends_a_command_as_ctrl_c_does_with_status_143(tmp_path, capsys, monkeypatch):
    """Issue 39: SIGTERM takes the Ctrl-C path (the same line; status 128 + 15), and the command's
    handler is only the command's: the caller's is back afterwards."""
    import signal
    import time

    from solver.retarget import pipeline

    def terminated(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(10)  # the handler raises well before
        raise AssertionError("SIGTERM did not interrupt the command")

    def callers(signum, frame):  # this process's own handler (the default would end the test run)
        raise AssertionError("SIGTERM reached the caller's handler, not the command's")

    fake_motion(monkeypatch)
    monkeypatch.setattr(pipeline, "retarget", terminated)
    before = signal.signal(signal.SIGTERM, callers)
    try:
        out = tmp_path / "out"
        assert main(["retarget", "grasp.npz", "--target", "alien", "-o", str(out)]) == 143
        assert one_line(capsys.readouterr().err) == (
            "contact-edit retarget: interrupted; run the same command again to resume "
            f"(solved frames are kept in {out / 'frames'})"
        )
        assert signal.getsignal(signal.SIGTERM) is callers
    finally:
        signal.signal(signal.SIGTERM, before)


class FakeRetarget:
    """What the CLI reads of a retarget's result."""

    def __init__(self, warnings=None):
        self._summary = {"median_contact_distance_mm": 2.0, "median_marker_distance_mm": 5.0, "frames": 44}
        if warnings is not None:
            self._summary["warnings"] = warnings
        self.seconds = {"root": 1.0, "full": 3.0}
        self.table = None
        self.motion = SimpleNamespace(fps=120.0)
        self.marker_distance = np.full(44, 0.005)
        self.contact_distance = np.full(44, 0.002)
        self.intersections = None
        self.transferred = SimpleNamespace(hand_contacts=SimpleNamespace(count=lambda: np.full(44, 30)))

    def summary(self):
        return dict(self._summary)


def test_the_retarget_prints_each_warning_of_its_summary(tmp_path, capsys, monkeypatch):
    from solver.retarget import pipeline

    fake_motion(monkeypatch)
    monkeypatch.setattr(pipeline, "save_result", lambda result, out, annotation, plot, rig, title: {})
    warnings = ["the final contact distance (9.1 mm) is far worse than the per-frame estimate (2.0 mm)",
                "12 frames were masked"]  # fmt: skip
    monkeypatch.setattr(pipeline, "retarget", lambda *a, **k: FakeRetarget(warnings))
    args = ["retarget", "grasp.npz", "--target", "alien", "-o", str(tmp_path / "out"), "--no-plot"]
    assert main(args) == 0
    captured = capsys.readouterr()
    assert "median contact distance: 2.00 mm" in captured.out and "warning" not in captured.out
    assert [line for line in captured.err.splitlines() if "warning" in line] == [
        f"  warning: {w}" for w in warnings
    ]
    # A summary without the key (as today's) prints none.
    monkeypatch.setattr(pipeline, "retarget", lambda *a, **k: FakeRetarget())
    assert main(args) == 0
    assert "warning" not in capsys.readouterr().err


def test_the_retarget_titles_its_plot(tmp_path, capsys, monkeypatch):
    from solver.retarget import pipeline

    fake_motion(monkeypatch)
    monkeypatch.setattr(pipeline, "retarget", lambda *a, **k: FakeRetarget())
    saved = {}

    def save_result(result, out, annotation, plot, rig, title):
        saved.update(out=out, plot=plot, title=title)
        return {"plot": out / "metrics.png"}

    monkeypatch.setattr(pipeline, "save_result", save_result)
    out = tmp_path / "out"
    assert main(["retarget", str(tmp_path / "grasp.npz"), "--target", "alien", "-o", str(out)]) == 0
    plots = importlib.util.find_spec("matplotlib") is not None
    assert saved == {"out": out, "plot": plots, "title": "grasp.npz: 44 frames onto alien (scale 1)"}
    assert f"plot       {out / 'metrics.png'}" in capsys.readouterr().out


# ------------------------------------------------------------------------------- outputs and inputs


def test_synthesize_replaces_an_existing_file_only_with_overwrite(tmp_path, capsys, monkeypatch):
    """Issue 39: ``synthesize copy.blend`` wrote a motion over a .blend without asking; now a motion is
    only ever written as .npz, and an existing one replaced only with --overwrite."""
    from solver.retarget import synthetic

    blend = tmp_path / "copy.blend"
    blend.write_bytes(b"BLENDER-v500 a scene to keep")
    generate = synthetic.generate
    monkeypatch.setattr(synthetic, "generate", interrupt)  # nothing generated before the check
    for overwrite in ([], ["--overwrite"]):
        assert main(["synthesize", str(blend), "--frames", "60", *overwrite]) == 1
        assert one_line(capsys.readouterr().err) == (
            f"contact-edit synthesize: {blend}: the output is written as a .npz file, so its name must end "
            "in .npz (e.g. copy.npz)"
        )
    assert blend.read_bytes() == b"BLENDER-v500 a scene to keep"
    motion = tmp_path / "old.npz"
    motion.write_bytes(b"PK a motion to keep")
    assert main(["synthesize", str(motion), "--frames", "60"]) == 1
    assert one_line(capsys.readouterr().err) == (
        f"contact-edit synthesize: {motion} exists; choose another output, or pass --overwrite to replace it"
    )
    assert motion.read_bytes() == b"PK a motion to keep"
    monkeypatch.setattr(synthetic, "generate", generate)
    args = [
        "synthesize",
        str(motion),
        "--object",
        "sphere",
        "--frames",
        "44",
        "--density",
        "2",
        "--overwrite",
    ]
    assert main(args) == 0
    assert f"saved {motion}" in capsys.readouterr().out
    from solver.retarget import Motion

    assert Motion.load(motion).n_frames == 44


@pytest.mark.parametrize(
    "name, hint", [("o11.txt", "o11.npz"), ("o11", "o11.npz"), ("motion.npz.tmp", "motion.npz")]
)
def test_a_motion_output_named_with_another_extension_is_refused_before_any_work(
    name, hint, tmp_path, capsys, monkeypatch
):
    """Issue 39: ``-o o11.txt`` wrote a file whose name hides its format. synthesize and import-grab
    write a motion (.npz, any case)."""
    from solver.retarget import synthetic

    monkeypatch.setattr(synthetic, "generate", never)
    monkeypatch.chdir(tmp_path)
    said = f"{name}: the output is written as a .npz file, so its name must end in .npz (e.g. {hint})"
    assert main(["synthesize", name]) == 1
    assert one_line(capsys.readouterr().err) == f"contact-edit synthesize: {said}"
    grab = ["import-grab", "grab.npz", "--hand-mesh", "h.obj", "--object-mesh", "o.obj", "-o", name]
    assert main(grab) == 1
    assert one_line(capsys.readouterr().err) == f"contact-edit import-grab: {said}"
    assert list(tmp_path.iterdir()) == []
    from contact_edit_addon.commands.outputs import check_outputs

    check_outputs([tmp_path / "UPPER.NPZ"], {}, suffix=".npz")  # the extension in any case


def test_a_retarget_never_writes_over_its_inputs_even_with_overwrite(tmp_path, capsys, monkeypatch):
    """Issue 39: ``retarget w3/motion.npz -o w3`` replaced its source with the target hand's motion.npz.
    Every file the retarget writes is checked, those in its output folder and its frames folder too."""
    from solver.retarget import pipeline

    monkeypatch.setattr(pipeline, "retarget", lambda *a, **k: 1 / 0)  # never reached
    w3 = tmp_path / "w3"
    w3.mkdir()
    source = w3 / "motion.npz"
    source.write_bytes(b"PK a witch's motion")
    for overwrite in ([], ["--overwrite"]):
        assert main(["retarget", str(source), "--target", "alien", "-o", str(w3), *overwrite]) == 1
        assert one_line(capsys.readouterr().err) == (
            f"contact-edit retarget: {source} is the source motion: an input, never written, even with "
            "--overwrite; choose another output folder (-o)"
        )
    # Spelled otherwise, through a hard link, in a folder holding a run's frames: still the input.
    (w3 / "frames").mkdir()
    os.link(source, tmp_path / "alias.npz")
    assert main(["retarget", str(tmp_path / "alias.npz"), "--target", "alien", "-o", f"{w3}/../w3/"]) == 1
    assert f"{w3}/../w3/motion.npz is the source motion: an input" in one_line(capsys.readouterr().err)
    (tmp_path / "alias.npz").unlink()
    # The annotation, as a previous run wrote it, given back into that folder.
    (w3 / "annotation.json").write_text('{"an": "annotation"}')
    args = ["retarget", str(tmp_path / "m.npz"), "--target", "alien", "-o", str(w3), "--overwrite"]
    assert main([*args, "--annotation", str(w3 / "annotation.json")]) == 1
    assert f"{w3 / 'annotation.json'} is the annotation (--annotation): an input" in capsys.readouterr().err
    # An input inside the frames folder, whose files are named as the run goes.
    (w3 / "frames" / "root").mkdir()
    (w3 / "frames" / "root" / "drawn.json").write_text("{}")
    assert main([*args, "--annotation", str(w3 / "frames" / "root" / "drawn.json")]) == 1
    assert one_line(capsys.readouterr().err) == (
        f"contact-edit retarget: {w3 / 'frames' / 'root' / 'drawn.json'} is the annotation (--annotation): "
        f"an input, inside {w3 / 'frames'}, which this command fills with its work; move the input or "
        "choose another output folder (-o)"
    )
    assert source.read_bytes() == b"PK a witch's motion"
    assert (w3 / "annotation.json").read_text() == '{"an": "annotation"}'


def test_a_retarget_replaces_results_outside_a_run_only_with_overwrite(tmp_path, capsys, monkeypatch):
    """A folder without a run's frames is not the run's own: its files are replaced only with
    --overwrite. A folder holding frames is resumed (another run's frames are refused when read)."""
    from solver.retarget import pipeline

    fake_motion(monkeypatch)
    monkeypatch.setattr(pipeline, "retarget", lambda *a, **k: FakeRetarget())
    saved = []
    monkeypatch.setattr(pipeline, "save_result", lambda result, out, *a, **k: saved.append(out) or {})
    out = tmp_path / "out"
    out.mkdir()
    (out / "summary.json").write_text("mine")
    args = ["retarget", str(tmp_path / "grasp.npz"), "--target", "alien", "-o", str(out), "--no-plot"]
    assert main(args) == 1
    assert one_line(capsys.readouterr().err) == (
        f"contact-edit retarget: {out / 'summary.json'} exists; choose another output folder (-o), or pass "
        "--overwrite to replace it"
    )
    assert saved == [] and (out / "summary.json").read_text() == "mine"
    assert main([*args, "--overwrite"]) == 0 and saved == [out]
    (out / "frames").mkdir()  # as a run leaves it: the same command again resumes
    assert main(args) == 0 and saved == [out, out]


def test_outputs_are_compared_with_inputs_as_files(tmp_path):
    """check_outputs: the same file however it is named (a relative path, .., a symlink, a hard link);
    existing outputs refused unless overwrite; an input inside a work folder, at any depth."""
    from contact_edit_addon.commands.outputs import check_outputs

    scene = tmp_path / "scene.blend"
    scene.write_bytes(b"scene")
    (tmp_path / "link.blend").symlink_to(scene)
    os.link(scene, tmp_path / "hard.blend")
    for output in (
        scene,
        tmp_path / "sub" / ".." / "scene.blend",
        tmp_path / "link.blend",
        tmp_path / "hard.blend",
    ):
        for overwrite in (False, True):
            with pytest.raises(FileExistsError, match="is the scene: an input, never written"):
                check_outputs([output], {scene: "the scene"}, overwrite=overwrite)
    other = tmp_path / "other.blend"
    check_outputs([other], {scene: "the scene", None: "no file given"})  # new: fine
    other.write_bytes(b"")
    with pytest.raises(FileExistsError, match=r"other\.blend exists; choose another output, or pass --over"):
        check_outputs([other], {scene: "the scene"})
    check_outputs([other], {scene: "the scene"}, overwrite=True)
    with pytest.raises(FileExistsError, match=r"inside .*, which this command fills with its work"):
        check_outputs([], {scene: "the scene"}, folders=[tmp_path.parent])
    check_outputs([], {scene: "the scene"}, folders=[tmp_path / "frames"])


def never(*args, **kwargs):
    raise AssertionError("the work started before the options were checked")


# Every count option, with a value it refuses and what it says (argparse: exit status 2, before any work).
REFUSED_COUNTS = [
    (["bench", "geodesics", "--rays", "0"], "argument --rays: must be at least 1, got 0"),
    (["bench", "geodesics", "--repeat", "-3"], "argument --repeat: must be at least 1, got -3"),
    (["bench", "layouts", "--per-bin", "0"], "argument --per-bin: must be at least 1, got 0"),
    (["bench", "retarget", "--frames", "0"], "argument --frames: must be at least 1, got 0"),
    (["bench", "solver", "--repeat", "two"], "argument --repeat: 'two' is not a whole number"),
    (["synthesize", "m.npz", "--frames", "0"], "argument --frames: must be at least 1, got 0"),
    (["retarget", "m.npz", "--target", "alien", "-o", "out", "--workers", "0"],
     "argument --workers: must be at least 1, got 0"),
    (["retarget", "m.npz", "--target", "alien", "-o", "out", "--workers", "-2"],
     "argument --workers: must be at least 1, got -2"),
    (["retarget", "m.npz", "--target", "alien", "-o", "out", "--control", "0"],
     "argument --control: must be at least 4 (a cubic spline's degree + 1), got 0"),
    (["retarget", "m.npz", "--target", "alien", "-o", "out", "--control", "-1"],
     "argument --control: must be at least 4 (a cubic spline's degree + 1), got -1"),
    (["retarget", "m.npz", "--target", "alien", "-o", "out", "--control", "2"],
     "argument --control: must be at least 4 (a cubic spline's degree + 1), got 2"),
]  # fmt: skip


@pytest.mark.parametrize("args, said", REFUSED_COUNTS, ids=[" ".join(a[-2:]) for a, _ in REFUSED_COUNTS])
def test_count_options_refuse_counts_below_their_least_before_any_work(
    args, said, tmp_path, capsys, monkeypatch
):
    """Issue 39: ``--rays 0`` ended in a numpy broadcasting error, ``--control 2`` only after every
    frame's solve, ``--control 0`` and ``--workers 0`` silently meant the default."""
    from geodesics import benchmark
    from solver import benchmark as solver_benchmark
    from solver import layout_benchmark
    from solver.retarget import benchmark as retarget_benchmark
    from solver.retarget import pipeline, synthetic

    for module in (benchmark, layout_benchmark, solver_benchmark, retarget_benchmark):
        monkeypatch.setattr(module, "run", never)
    monkeypatch.setattr(synthetic, "generate", never)
    monkeypatch.setattr(pipeline, "retarget", never)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exit_:
        main(args)
    assert exit_.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1].endswith(f": error: {said}")
    assert list(tmp_path.iterdir()) == []


def test_every_count_option_is_checked_by_the_shared_count_type():
    """No option parses a count with a bare ``int`` (which takes 0 and negatives); the only whole numbers
    that may be anything are a frame number and a seed. The spline's least count is the solver's."""
    import argparse

    from contact_edit_addon.commands import cli
    from solver.retarget.spline import DEGREE

    parser = cli.build_parser()
    [commands] = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    counted, free = set(), set()
    for name, sub in commands.choices.items():
        for action in sub._actions:
            if getattr(action.type, "__name__", None) == "count":
                counted.add(f"{name} {action.option_strings[0]}")
            elif action.type is int:
                free.add(f"{name} {action.option_strings[0]}")
    assert free == {"pose --frame", "synthesize --seed"}
    assert counted == {
        "bench --repeat", "bench --rays", "bench --frames", "bench --per-bin", "synthesize --frames",
        "retarget --workers", "retarget --control",
    }  # fmt: skip
    assert cli._SPLINE_LEAST == DEGREE + 1
    args = parser.parse_args(["retarget", "m.npz", "--target", "alien", "-o", "out", "--control", "4"])
    assert args.control == 4 and args.workers is None  # absent: the default, decided by the pipeline
