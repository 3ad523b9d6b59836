"""The ``contact-edit`` command."""

import importlib.util
import re

import pytest

from contact_edit_addon.commands.cli import main


def test_bench_geodesics_prints_the_table(capsys, monkeypatch):
    from geodesics import benchmark

    monkeypatch.setattr(benchmark, "WHOLE_FIELD_TORI", ((40, 20), (60, 30)))  # not 1M faces again
    assert main(["bench", "geodesics", "--repeat", "1", "--rays", "20"]) == 0
    out = capsys.readouterr().out
    assert "exp_map: 20 rays" in out
    assert "log_map (exact)" in out
    assert "1M faces" in out and "GiB" in out
    assert "potpourri3d" in out and "pygeodesic" in out
    # Peak resident memory of whole-mesh fields, each measured in its own process, pygeodesic's beside.
    small = re.search(
        r"whole-mesh exact field, 1,600 faces .*peak resident ([\d.]+) GiB.*pygeodesic: peak", out
    )
    assert small and 0 < float(small.group(1)) < 2
    assert re.search(r"whole-mesh exact field, 3,600 faces .*peak resident ([\d.]+) GiB", out)


@pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="needs bpy (the dev extra)")
def test_bench_operators_times_every_interactive_operator_on_the_demo_scene(tmp_path):
    """In a fresh process: the benchmark builds the demo scene in the bpy module it imports."""
    from .blender import contact_edit

    done = contact_edit("bench", "operators", "--repeat", "1", cwd=tmp_path, user_dir=tmp_path)
    assert done.returncode == 0, done.stderr
    for task in ("translate the palm", "rotate the palm", "bend the palm", "paint 108 selected vertices",
                 "axis of the index tip (farthest pair", "axis of the index tip (medial",
                 "transfer the index tip", "solve from the open hand: plan, first better pose",
                 "solve: plan (the main thread's part)", "retarget: invoke",
                 "retarget: read a frame"):  # fmt: skip
        (line,) = [line for line in done.stdout.splitlines() if line.startswith(task)]
        assert re.search(r"\d+\.\d ms +100\.0 ms .* goal; longest \d+\.\d ms", line), line


def test_bad_arguments_are_refused(capsys):
    with pytest.raises(SystemExit):
        main(["bench", "nothing"])
    with pytest.raises(SystemExit):
        main(["bench", "geodesics", "--repeat", "0"])
    assert "argument --repeat: must be at least 1, got 0" in capsys.readouterr().err


def test_bench_tangible_prints_link_interpolation_and_reduction_rows(capsys, monkeypatch):
    from functools import partial

    from tangible import benchmark

    monkeypatch.setattr(benchmark, "run", partial(benchmark.run, seconds=1.0))
    curve = partial(benchmark.run_reduction_curve, n_bones=20, kit_sizes=(0, 3), n_poses=4)
    monkeypatch.setattr(benchmark, "run_reduction_curve", curve)
    assert main(["bench", "tangible", "--repeat", "1"]) == 0
    out = capsys.readouterr().out
    # The simulated firmware on its poll cycle; what reaches the host is measured, and nothing valid lost.
    assert "link latency, 25 joints on the firmware's 20 ms poll cycle" in out
    lost = re.search(r"valid records lost: (\d+) of (\d+)", out)
    assert lost and lost.group(1) == "0" and int(lost.group(2)) > 100
    assert "pose interpolation per update, 100 bones" in out
    assert "Fig. 7: 20 bones, 4 poses,  0 joints" in out and "pose error 100.0%" in out
    assert "Fig. 7: 20 bones, 4 poses,  3 joints" in out


def test_version_and_help_say_what_the_command_is(capsys):
    from importlib.metadata import version

    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.strip() == f"contact-edit {version('contact-edit')}"
    with pytest.raises(SystemExit):
        main(["--help"])
    text = capsys.readouterr().out
    assert "Pose hands against objects" in text and "``" not in text  # not the module's raw docstring
    with pytest.raises(SystemExit):
        main(["ablation", "-h"])
    assert "each term of Contact Edit's Eq. 2 removed" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["synthesize", "-h"])
    assert "the object the hand manipulates (default: mug)" in " ".join(capsys.readouterr().out.split())
