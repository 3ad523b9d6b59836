"""`contact-edit pose` on input a newcomer may give it: a file that is not a .blend, a truncated one, a
scene without a chosen hand. One line saying what is wrong with which file, exit status 1, nothing
written, nothing of Blender's own output, and the traceback only with --debug."""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from .blender import contact_edit, fresh_process, run_blender

pytestmark = pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="needs bpy (the dev extra)")

PREVIOUS = b"a previous output, to be left as it is"


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> Path:
    """A tiny real scene (two meshes, no Contact tab choice), and broken files made from it."""
    folder = tmp_path_factory.mktemp("pose-input")
    run_blender(
        f"""
        bpy.ops.wm.read_factory_settings(use_empty=True)
        bpy.ops.mesh.primitive_cube_add()
        bpy.ops.mesh.primitive_uv_sphere_add(location=(3, 0, 0))
        bpy.context.object.name = "Ball"
        bpy.ops.wm.save_as_mainfile(filepath={str(folder / "tiny.blend")!r})
        result(True)
        """,
        folder / "user",
    )
    data = (folder / "tiny.blend").read_bytes()
    assert len(data) > 1000
    (folder / "truncated.blend").write_bytes(data[: len(data) // 2])
    (folder / "random.blend").write_bytes(np.random.default_rng(7).bytes(4096))
    (folder / "empty.blend").write_bytes(b"")
    return folder


def assert_nothing_written(folder: Path, before: set[str]) -> None:
    assert (folder / "out.blend").read_bytes() == PREVIOUS
    assert {p.name for p in folder.iterdir()} == before  # no temporary file either


@pytest.mark.parametrize(
    "name, reason",
    [
        ("random", "not a .blend file (Blender does not recognize its contents)"),
        ("truncated", "a damaged or truncated .blend file (Blender: Missing DNA block)"),
        ("empty", "an empty file, not a .blend file"),
        ("missing", "no such .blend file"),
    ],
)
def test_a_file_blender_cannot_open_is_one_line_and_nothing_is_written(files, name, reason):
    (files / "out.blend").write_bytes(PREVIOUS)
    before = {p.name for p in files.iterdir()}
    done = contact_edit(
        "pose", f"{name}.blend", "-o", "out.blend", "--overwrite", cwd=files, user_dir=files / "user"
    )  # an output it may replace, kept as it was
    assert done.returncode == 1
    assert done.stderr.splitlines() == [f"contact-edit pose: {files / name}.blend: {reason}"]
    assert done.stdout == ""  # not Blender's "Error: File format is not supported …" or "Read blend: …"
    assert_nothing_written(files, before)


def test_debug_shows_the_traceback_and_blenders_own_error(files):
    (files / "out.blend").write_bytes(PREVIOUS)
    before = {p.name for p in files.iterdir()}
    done = contact_edit(
        "--debug",
        "pose",
        "truncated.blend",
        "-o",
        "out.blend",
        "--overwrite",
        cwd=files,
        user_dir=files / "user",
    )
    assert done.returncode == 1
    assert "Traceback (most recent call last):" in done.stderr
    assert "RuntimeError: Error: Loading" in done.stderr  # what Blender raised, chained
    assert done.stderr.splitlines()[-1].startswith("contact-edit pose: ")
    assert "Missing DNA block" in done.stdout  # Blender's own report, not hidden with --debug
    assert_nothing_written(files, before)


def test_a_scene_without_a_chosen_hand_names_the_command_line_options(files):
    done = contact_edit("pose", "tiny.blend", "-o", "posed.blend", cwd=files, user_dir=files / "user")
    assert done.returncode == 1 and done.stdout == ""
    assert done.stderr.splitlines() == [
        f"contact-edit pose: {files / 'tiny.blend'}: no hand and no object chosen in the scene's Contact "
        "tab; name them with --hand NAME --object NAME (mesh objects: Ball, Cube)"
    ]
    done = contact_edit(
        "pose", "tiny.blend", "--hand", "Cube", "-o", "posed.blend", cwd=files, user_dir=files / "user"
    )
    assert done.returncode == 1
    [line] = done.stderr.splitlines()
    assert "no object chosen" in line and "name it with --object NAME (mesh objects: Ball, Cube)" in line
    assert "--hand" not in line and "Contact tab first" not in line
    # Both named, but nothing to pose: still one line, naming the scene.
    done = contact_edit(
        "pose",
        "tiny.blend",
        "--hand",
        "Cube",
        "--object",
        "Ball",
        "-o",
        "posed.blend",
        cwd=files,
        user_dir=files / "user",
    )
    assert done.returncode == 1
    [line] = done.stderr.splitlines()
    assert line.startswith(f"contact-edit pose: {files / 'tiny.blend'}: ") and "Traceback" not in done.stderr
    assert not (files / "posed.blend").exists()


def test_quiet_stdout_drops_c_level_output_and_restores_the_descriptor(tmp_path):
    """What Blender's C code prints (printf into the C library's buffer, or straight to descriptor 1) is
    dropped inside the block, even when the block fails; what is printed around it is kept, in order."""
    script = """
import ctypes, os, sys
from contact_edit_addon.commands.batch import quiet_stdout
libc = ctypes.CDLL(None)
print("before", flush=True)
libc.printf(b"c-before\\n")
with quiet_stdout():
    libc.printf(b"Info: Saved copy as .temp.blend\\n")
    os.write(1, b"raw\\n")
    print("python")
try:
    with quiet_stdout():
        libc.printf(b"buffered when it fails\\n")
        raise RuntimeError("inside")
except RuntimeError:
    pass
with quiet_stdout(enabled=False):
    print("shown", flush=True)
libc.printf(b"c-after\\n")
libc.fflush(None)
print("after", flush=True)
"""
    done = fresh_process([sys.executable, "-c", script], user_dir=tmp_path / "user", timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ["before", "c-before", "shown", "c-after", "after"]


def test_pose_never_writes_over_its_inputs_and_replaces_an_output_only_with_overwrite(files, tmp_path):
    """Issue 39: the scene and the pairing file are never written, even with --overwrite; another
    existing file is replaced only with --overwrite (which then gets as far as opening the scene)."""
    scene = tmp_path / "tiny.blend"
    scene.write_bytes((files / "tiny.blend").read_bytes())
    pairing = tmp_path / "contacts.json"
    pairing.write_text('{"format": "contact-edit/pairing"}')
    kept = {scene: scene.read_bytes(), pairing: pairing.read_bytes()}
    for output, what in ((scene, "the input scene"), (pairing, "the pairing file (--contacts)")):
        done = contact_edit(
            "pose", "tiny.blend", "--contacts", "contacts.json", "-o", output.name, "--overwrite",
            cwd=tmp_path, user_dir=files / "user",
        )  # fmt: skip
        assert done.returncode == 1 and done.stdout == ""
        assert done.stderr.splitlines() == [
            f"contact-edit pose: {output} is {what}: an input, never written, even with --overwrite; "
            "choose another output"
        ]
    assert {p: p.read_bytes() for p in kept} == kept
    (tmp_path / "out.blend").write_bytes(PREVIOUS)
    done = contact_edit("pose", "tiny.blend", "-o", "out.blend", cwd=tmp_path, user_dir=files / "user")
    assert done.returncode == 1
    assert done.stderr.splitlines() == [
        f"contact-edit pose: {tmp_path / 'out.blend'} exists; choose another output, or pass --overwrite to "
        "replace it"
    ]
    done = contact_edit(
        "pose", "tiny.blend", "-o", "out.blend", "--overwrite", cwd=tmp_path, user_dir=files / "user"
    )
    assert done.returncode == 1 and "no hand and no object chosen" in done.stderr  # past the check
    assert (tmp_path / "out.blend").read_bytes() == PREVIOUS and scene.read_bytes() == kept[scene]


@pytest.fixture(scope="module")
def hand_scene(tmp_path_factory) -> tuple[Path, list[str]]:
    """The example scene (a rigged hand beside a mug, chosen in the Contact tab, no contacts yet), a copy
    whose Contact tab chose the hand as the object too, and what the add-on's own solve setup says when
    the object is the hand, then its armature."""
    folder = tmp_path_factory.mktemp("pose-hand")
    said = run_blender(
        f"""
        import numpy as np
        import contact_edit_addon
        from contact_edit_addon import assets, bridge, posing
        contact_edit_addon.register()
        bpy.ops.wm.read_factory_settings(use_empty=True)
        assets.example_scene(bpy.context, np.zeros(3))
        bpy.ops.wm.save_as_mainfile(filepath={str(folder / "hand.blend")!r})
        settings = bpy.context.scene.contact_edit
        said = []
        for target in (settings.hand, settings.hand.parent):
            settings.target = target
            try:
                posing.problem(bpy.context.scene)
            except bridge.BridgeError as err:
                said.append(str(err))
        settings.target = settings.hand
        bpy.ops.wm.save_as_mainfile(filepath={str(folder / "itself.blend")!r})
        result(said)
        """,
        folder / "user",
    )
    return folder, said


def test_posing_the_hand_against_itself_or_its_armature_is_refused_before_solving(hand_scene):
    """Issue 39: ``pose … --object Hand`` solved the hand against its own skin ("0 of 6 patches touch
    'Hand'", exit status 0). Refused in one line naming the option and the object, nothing written."""
    folder, said = hand_scene
    scene, user = folder / "hand.blend", folder / "user"
    for name, what in (("Hand", "the hand itself"), ("Hand rig", "the hand's armature")):
        done = contact_edit(
            "pose", "hand.blend", "--object", name, "-o", "posed.blend", cwd=folder, user_dir=user
        )
        assert done.returncode == 1 and done.stdout == ""
        assert done.stderr.splitlines() == [
            f"contact-edit pose: {scene}: --object '{name}' is {what}, not a mesh the hand touches; name the "
            "object with --object NAME (mesh objects: Mug)"
        ]
    done = contact_edit("pose", "itself.blend", "-o", "posed.blend", cwd=folder, user_dir=user)
    assert done.returncode == 1
    assert done.stderr.splitlines() == [
        f"contact-edit pose: {folder / 'itself.blend'}: the object chosen in the scene's Contact tab, "
        "'Hand', is the hand itself, not a mesh the hand touches; name the object with --object NAME "
        "(mesh objects: Mug)"
    ]
    assert not (folder / "posed.blend").exists()
    # The add-on's solve (the operator's, a script's) refuses it the same way.
    assert said == [
        "the object 'Hand' is the hand itself; choose the mesh the hand touches as the object",
        "the object 'Hand rig' is the hand's armature; choose the mesh the hand touches as the object",
    ]


def test_a_posed_scene_is_only_written_under_a_blend_name(files, tmp_path):
    """Issue 39: ``pose … -o o11.txt`` wrote a .blend named .txt. Refused before the scene is opened (an
    output named so, even one that exists, is kept as it is, --overwrite or not)."""
    (tmp_path / "o11.txt").write_bytes(PREVIOUS)
    for name, overwrite in (("o11.txt", ["--overwrite"]), ("posed", [])):
        done = contact_edit(
            "pose", str(files / "tiny.blend"), "-o", name, *overwrite, cwd=tmp_path, user_dir=files / "user"
        )
        assert done.returncode == 1 and done.stdout == ""
        assert done.stderr.splitlines() == [
            f"contact-edit pose: {tmp_path / name}: the output is written as a .blend file, so its name must "
            f"end in .blend (e.g. {Path(name).stem}.blend)"
        ]
    assert [p.name for p in tmp_path.iterdir()] == ["o11.txt"] and (
        tmp_path / "o11.txt"
    ).read_bytes() == PREVIOUS
