"""The README's main job and the batch paths: ``contact-edit demo``, ``contact-edit pose`` and the
``blender --background … --python-expr`` line, run exactly as a user runs them."""

import hashlib
import importlib.util
import json
import os
import re
import struct
import subprocess
import sys
from pathlib import Path

import pytest

from .blender import run_blender

pytestmark = pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="needs bpy (the dev extra)")

README = Path(__file__).parents[1] / "README.md"
OPEN = """
import numpy as np
import contact_edit_addon
contact_edit_addon.register()
"""


def contact_edit(*args: str, cwd: Path, user_dir: Path) -> subprocess.CompletedProcess:
    """The console script, as installed, in a fresh process with a temporary Blender user folder."""
    env = {**os.environ, "BLENDER_USER_RESOURCES": str(user_dir)}
    command = [
        sys.executable,
        "-c",
        "import sys; from contact_edit_addon.cli import main; sys.exit(main())",
        *args,
    ]
    return subprocess.run(command, capture_output=True, text=True, cwd=cwd, env=env, timeout=600)


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def demo(tmp_path_factory) -> tuple[Path, str]:
    folder = tmp_path_factory.mktemp("demo")
    done = contact_edit("demo", "--out", str(folder / "out"), cwd=folder, user_dir=folder / "user")
    assert done.returncode == 0, done.stderr
    return folder / "out", done.stdout


def test_demo_paints_transfers_solves_keys_saves_and_renders(demo, tmp_path):
    out, printed = demo
    assert "patches transferred onto the mug" in printed and ", converged" in printed
    value, unit = re.search(r"mean distance ([0-9.]+) (µm|mm|cm|m)\b", printed).groups()
    mean = float(value) * {"µm": 1e-6, "mm": 1e-3, "cm": 1e-2, "m": 1.0}[unit]
    assert 0 < mean < 0.01  # metres, on a hand 19 cm long
    with open(out / "demo.png", "rb") as f:
        header = f.read(24)
    assert header[:8] == b"\x89PNG\r\n\x1a\n" and struct.unpack(">II", header[16:24]) == (480, 360)
    found = run_blender(
        f"""
        bpy.ops.wm.open_mainfile(filepath={str(out / "demo.blend")!r})
        from contact_edit_addon import bridge, store
        from solver.sdf import MeshSDF
        scene = bpy.context.scene
        hand, mug = scene.contact_edit.hand, scene.contact_edit.target
        armature = hand.modifiers["Armature"].object
        hand_set, mug_set = store.load(hand), store.load(mug)
        scene.frame_set(24)
        evaluated = hand.evaluated_get(bpy.context.evaluated_depsgraph_get())
        mesh = evaluated.to_mesh()
        V = np.array([v.co[:] for v in mesh.vertices]); evaluated.to_mesh_clear()
        H, M = np.array(hand.matrix_world), np.array(mug.matrix_world)
        world = V @ H[:3, :3].T + H[:3, 3]
        sdf = MeshSDF(bridge.trimesh(mug))((world - M[:3, 3]) @ M[:3, :3], np.inf)
        weights = np.zeros((len(V), len(hand.vertex_groups)))
        for v in hand.data.vertices:
            for g in v.groups:
                weights[v.index, g.group] = g.weight
        owner = [hand.vertex_groups[i].name for i in np.argmax(weights, axis=1)]
        inside = sorted({{owner[i] for i in np.flatnonzero(sdf < 0)}})
        result(dict(hand=hand.name, mug=mug.name, hand_patches=len(hand_set), mug_patches=len(mug_set),
                    pairs={{k: v for k, v in hand_set.pairs.items()}}, keyed=keyed_frames(armature),
                    depth=float(-sdf.min()), inside=inside, summary=scene.contact_edit.last_solve))
        """,
        tmp_path,
        setup=OPEN,
    )
    assert (found["hand"], found["mug"]) == ("Hand", "Mug")
    assert found["hand_patches"] == 10 and found["mug_patches"] == len(found["pairs"]) >= 4
    assert found["keyed"] == [1.0, 24.0]  # the open hand, then the grasp
    # Eq. 2 presses each round pad onto its patch: only the paired pads enter the mug, by a few millimetres
    # (about what a real finger pad gives), and nothing else does.
    pads = {"hand"} | {f"{finger}_3" for finger in ("thumb", "index", "middle", "ring", "pinky")}
    assert set(found["inside"]) <= pads and found["depth"] < 0.005
    assert "contacts in" in found["summary"]


def test_pose_command_poses_a_copy_and_never_writes_its_input(demo, tmp_path):
    out, _ = demo
    scene = out / "demo.blend"
    before = digest(scene)
    user = tmp_path / "user"

    done = contact_edit("pose", str(scene), "--frame", "30", "-o", "posed.blend", cwd=tmp_path, user_dir=user)
    assert done.returncode == 0, done.stderr
    assert "solving [" in done.stderr and "contacts in" in done.stdout
    assert digest(scene) == before

    refused = contact_edit("pose", str(scene), "-o", str(scene), cwd=tmp_path, user_dir=user)
    assert refused.returncode == 1 and "is the input scene" in refused.stderr
    corrupt = tmp_path / "corrupt.json"
    corrupt.write_text('{"format": "contact-edit/pairing", "version": 1, "hand": {"format": ')
    bad = contact_edit(
        "pose", str(scene), "--contacts", str(corrupt), "-o", "bad.blend", cwd=tmp_path, user_dir=user
    )
    assert bad.returncode == 1 and "cannot read a pairing file" in bad.stderr
    missing = contact_edit(
        "pose", str(scene), "--hand", "Nope", "-o", "bad.blend", cwd=tmp_path, user_dir=user
    )
    assert missing.returncode == 1 and "no object 'Nope' (mesh objects: Hand, Mug)" in missing.stderr
    foreign = tmp_path / "foreign.json"
    pairing = json.loads((out / "contacts.json").read_text())
    pairing["hand"]["mesh"]["hash"] = "0" * 64  # as if made for another hand
    foreign.write_text(json.dumps(pairing))
    refused = contact_edit(
        "pose", str(scene), "--contacts", str(foreign), "-o", "bad.blend", cwd=tmp_path, user_dir=user
    )
    assert refused.returncode == 1 and "(hand 'Hand'): made for another mesh" in refused.stderr
    assert not (tmp_path / "bad.blend").exists() and digest(scene) == before
    remapped = contact_edit(
        "pose", str(scene), "--contacts", str(foreign), "--remap", "-o", "remapped.blend",
        cwd=tmp_path, user_dir=user,
    )  # fmt: skip
    assert remapped.returncode == 0, remapped.stderr

    again = contact_edit(
        "pose", str(scene), "--contacts", str(out / "contacts.json"), "--frame", "40", "-o", "again.blend",
        cwd=tmp_path, user_dir=user,
    )  # fmt: skip
    assert again.returncode == 0, again.stderr
    found = run_blender(
        f"""
        frames = {{}}
        for name in ("posed", "again"):
            bpy.ops.wm.open_mainfile(filepath={str(tmp_path)!r} + "/" + name + ".blend")
            frames[name] = keyed_frames(bpy.data.objects["Hand rig"])
        result(frames)
        """,
        tmp_path,
        setup=OPEN,
    )
    assert found == {"posed": [1.0, 24.0, 30.0], "again": [1.0, 24.0, 40.0]}


def test_readme_blender_background_line(demo, tmp_path):
    """The README's line for users with a Blender install: its --python-expr body, run on the demo scene."""
    line = next(line for line in README.read_text().splitlines() if line.startswith("blender --background"))
    scene_argument, body = re.fullmatch(r'blender --background (\S+) --python-expr "(.*)"', line).groups()
    assert scene_argument == "demo/demo.blend"
    out, _ = demo
    found = run_blender(
        f"""
        import os
        bpy.ops.wm.open_mainfile(filepath={str(out / "demo.blend")!r})
        os.chdir({str(tmp_path)!r})
        exec({body!r})
        bpy.ops.wm.open_mainfile(filepath="posed.blend")
        keyed = keyed_frames(bpy.data.objects["Hand rig"])
        scene = bpy.context.scene
        result(dict(keyed=keyed, summary=scene.contact_edit.last_solve,
                    frames=[scene.frame_start, scene.frame_end]))
        """,
        tmp_path,
        setup=OPEN,
    )
    assert found["keyed"] == [1.0, 12.0, 24.0]  # the README's frame, inside the demo's timeline
    assert found["frames"] == [1, 24]
    assert "contacts in" in found["summary"]
