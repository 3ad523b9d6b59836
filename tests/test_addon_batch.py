"""The README's main job and the batch paths: ``contact-edit demo``, ``contact-edit pose`` and the
``blender --background … --python-expr`` line, run exactly as a user runs them."""

import hashlib
import importlib.util
import json
import re
import struct
from pathlib import Path

import pytest

from .blender import contact_edit, run_blender

pytestmark = pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="needs bpy (the dev extra)")

README = Path(__file__).parents[1] / "README.md"
OPEN = """
import numpy as np
import contact_edit_addon
contact_edit_addon.register()
"""


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_demo_paints_transfers_solves_keys_saves_and_renders(demo, tmp_path):
    """Measured on Blender's own evaluated mesh, not on the solver's skin: every pad the demo paints is
    transferred and touches the mug at the grasp, no vertex is 0.1 mm and no face 1 mm inside it; what
    the demo prints says the same; the render is denoised, on a floor that catches soft shadows."""
    out, printed = demo
    assert ", converged" in printed and "pads touching the mug after the solve: all 6" in printed
    value, unit = re.search(r"mean distance ([0-9.]+) (µm|mm|cm|m)\b", printed).groups()
    mean = float(value) * {"µm": 1e-6, "mm": 1e-3, "cm": 1e-2, "m": 1.0}[unit]
    assert 0 < mean < 0.003  # metres, on a hand 19 cm long
    printed_depth = float(re.search(r"deepest vertex of the hand inside the mug: ([0-9.]+) mm", printed)[1])
    printed_faces = float(re.search(r"deepest point of its faces inside the mug: ([0-9.]+) mm", printed)[1])
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
        solid = MeshSDF(bridge.trimesh(mug))
        def signed(points):
            return solid((points - M[:3, 3]) @ M[:3, :3], np.inf)
        corners = world[hand_set.mesh.faces]
        gaps = {{}}
        for name in hand_set:
            points = hand_set[name].points
            at = np.einsum("kc,kcd->kd", points.bary, corners[points.faces])
            gaps[name] = float(np.abs(signed(at)).min())
        # The skin's faces, not only its vertices: 45 points in each face near the mug.
        n = 8
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        bary = np.stack([i[i + j <= n], j[i + j <= n], (n - i - j)[i + j <= n]], 1) / n
        near = np.flatnonzero(signed(corners.mean(1)) < 0.01)
        samples = np.einsum("sc,fcd->fsd", bary, corners[near]).reshape(-1, 3)
        faces_depth = float(max(0.0, -signed(samples).min()))
        floor = bpy.data.objects.get("Floor")
        mug_z = min((M @ [*v.co, 1])[2] for v in mug.data.vertices)
        result(dict(hand=hand.name, mug=mug.name, patches=sorted(hand_set), mug_patches=len(mug_set),
                    pairs={{k: v for k, v in hand_set.pairs.items()}}, keyed=keyed_frames(armature),
                    depth=float(max(0.0, -signed(world).min())), faces_depth=faces_depth, gaps=gaps,
                    summary=scene.contact_edit.last_solve,
                    frames=[scene.frame_start, scene.frame_end], denoised=scene.cycles.use_denoising,
                    denoiser=scene.cycles.denoiser, sun=bpy.data.objects["Sun"].data.angle,
                    floor=None if floor is None else max(v.co.z for v in floor.data.vertices),
                    lowest=float(min(world[:, 2].min(), mug_z))))
        """,
        tmp_path,
        setup=OPEN,
    )
    assert (found["hand"], found["mug"]) == ("Hand", "Mug")
    pads = ["index tip", "middle tip", "palm", "pinky tip", "ring tip", "thumb tip"]
    assert found["patches"] == pads and found["pairs"] == {name: name for name in pads}
    assert found["mug_patches"] == 6
    assert found["keyed"] == [1.0, 24.0] and found["frames"] == [1, 24]  # the open hand, then the grasp
    # Every pad touches (its closest point within 1 mm of the mug's surface), thumb included, and the
    # skin stays out of the mug; the demo's own figure is Blender's.
    assert max(found["gaps"].values()) < 1e-3, found["gaps"]
    assert found["depth"] < 1e-4 and printed_depth == pytest.approx(1e3 * found["depth"], abs=0.01)
    assert found["faces_depth"] < 1e-3  # between vertices a face cuts the mug's rim a little deeper
    assert printed_faces == pytest.approx(1e3 * found["faces_depth"], abs=0.01)  # and the demo says so
    assert "all 6 patches touch 'Mug'" in found["summary"]
    assert found["denoised"] and found["denoiser"] == "OPENIMAGEDENOISE" and found["sun"] > 0
    assert found["floor"] == pytest.approx(found["lowest"], abs=1e-6)  # under everything, touching it


def test_pose_command_poses_a_copy_and_never_writes_its_input(demo, tmp_path):
    out, _ = demo
    scene = out / "demo.blend"
    before = digest(scene)
    user = tmp_path / "user"

    done = contact_edit("pose", str(scene), "--frame", "30", "-o", "posed.blend", cwd=tmp_path, user_dir=user)
    assert done.returncode == 0, done.stderr
    # Only our own lines: not Blender's "Read blend: …" nor "Info: Saved copy as" its temporary file.
    summary, saved = done.stdout.splitlines()
    assert summary.startswith("contact-edit pose: ") and "contacts in" in summary
    assert saved == "  saved posed.blend"
    # stderr is not a terminal here: plain progress lines, no bar redrawn with carriage returns.
    assert "\r" not in done.stderr
    assert re.search(r"^  solving +\d+/2000 energy \S+, \d+:\d\d elapsed$", done.stderr, re.MULTILINE)
    assert digest(scene) == before

    for overwrite in ((), ("--overwrite",)):  # never, even when told to (issue 39)
        refused = contact_edit("pose", str(scene), "-o", str(scene), *overwrite, cwd=tmp_path, user_dir=user)
        assert refused.returncode == 1 and "is the input scene: an input, never written" in refused.stderr
    posed = (tmp_path / "posed.blend").read_bytes()
    refused = contact_edit("pose", str(scene), "-o", "posed.blend", cwd=tmp_path, user_dir=user)
    assert refused.returncode == 1 and "posed.blend exists; choose another output, or pass --overwrite" in (
        refused.stderr
    )
    assert (tmp_path / "posed.blend").read_bytes() == posed
    done = contact_edit(
        "pose", str(scene), "--frame", "30", "-o", "posed.blend", "--overwrite", cwd=tmp_path, user_dir=user
    )
    assert done.returncode == 0, done.stderr
    corrupt = tmp_path / "corrupt.json"
    corrupt.write_text('{"format": "contact-edit/pairing", "version": 1, "hand": {"format": ')
    bad = contact_edit(
        "pose", str(scene), "--contacts", str(corrupt), "-o", "bad.blend", cwd=tmp_path, user_dir=user
    )
    assert bad.returncode == 1 and "cannot read the pairing file" in bad.stderr
    assert len(bad.stderr.splitlines()) == 1 and bad.stdout == ""  # one line, no traceback
    missing = contact_edit(
        "pose", str(scene), "--hand", "Nope", "-o", "bad.blend", cwd=tmp_path, user_dir=user
    )
    assert missing.returncode == 1 and "no object 'Nope' (mesh objects: Floor, Hand, Mug)" in missing.stderr
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


def test_the_example_with_the_issues_four_pads_touches_from_the_open_hand(tmp_path):
    """Issue 41's first case: the Example with four pads (index and middle tips, thumb tip, palm), each
    transferred where the wrapped fingers put it, solved from the open hand. Its hand already stands
    where the grasp is, only the fingers must wrap; a start laid onto the pads by a root fit alone went
    through the mug (1 of 4 touching, 4.8 mm deep, 10 s)."""
    found = run_blender(
        """
        import tempfile
        from contact_edit_addon.commands import demo
        four = ("palm", "thumb tip", "index tip", "middle tip")
        demo.PADS = {name: pad for name, pad in demo.PADS.items() if name in four}
        done = demo.run(tempfile.mkdtemp(), render=False)
        result({"transferred": sorted(done.transferred), "touching": sorted(done.touching),
                "deepest": done.deepest, "summary": done.summary})
        """,
        tmp_path,
        setup=OPEN,
    )
    assert found["transferred"] == ["index tip", "middle tip", "palm", "thumb tip"]
    assert found["touching"] == found["transferred"], found["summary"]
    assert found["deepest"] < 0.2e-3, found["summary"]


def test_demo_replaces_its_files_only_with_overwrite(tmp_path):
    """Issue 39: the demo wrote its .blend over an existing one without asking (checked before the work)."""
    (tmp_path / "demo").mkdir()
    (tmp_path / "demo" / "demo.blend").write_bytes(b"a scene of mine")
    done = contact_edit("demo", "--out", "demo", "--no-render", cwd=tmp_path, user_dir=tmp_path / "user")
    assert done.returncode == 1 and done.stdout == ""
    assert done.stderr.splitlines() == [
        "contact-edit demo: demo/demo.blend exists; choose another folder (--out), or pass --overwrite to "
        "replace it"
    ]
    assert (tmp_path / "demo" / "demo.blend").read_bytes() == b"a scene of mine"
