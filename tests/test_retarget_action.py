"""A retargeted motion written into the .blend (contact_edit_addon.retarget.action) in the real bpy module:
the action plays back, frame for frame, the poses apply_pose sets, on the keys apply_pose would key; its
quaternions never flip sign between keys; the metrics plot travels packed in the .blend."""

import importlib.util
import struct

import pytest

from .blender import run_blender

pytestmark = pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="needs bpy (the dev extra)")

SETUP = """
import time
import numpy as np
from mathutils import Euler, Matrix
from bpy_extras import anim_utils
import contact_edit_addon
contact_edit_addon.register()
from contact_edit_addon import assets, bridge
from contact_edit_addon.retarget import action as retarget_action
from contact_edit_addon.bridge import BridgeError
bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
PATHS = ("location", "rotation_quaternion", "rotation_euler", "rotation_axis_angle")

def procedural_hand(modes=None):
    # The example scene's human hand; `modes` gives some pose bones other rotation modes first.
    _, hand_obj, _ = assets.example_scene(bpy.context, np.array([0.3, -0.2, 0.1]))
    armature = hand_obj.modifiers["Armature"].object
    for name, mode in (modes or {}).items():
        armature.pose.bones[name].rotation_mode = mode
    faces = bridge.trimesh(hand_obj).faces
    return hand_obj, faces, bridge.posed_hand(hand_obj, faces)

def channels(armature):
    # Every pose bone's channels, as playback or apply_pose leave them.
    return {b.name: np.concatenate([np.array(getattr(b, p)) for p in PATHS]) for b in armature.pose.bones}

def set_channels(armature, values):
    for b in armature.pose.bones:
        v = values[b.name]
        b.location, b.rotation_quaternion = v[:3], v[3:7]
        b.rotation_euler, b.rotation_axis_angle = v[7:10], v[10:]

def table(action):
    # {(data_path, index): (frames, values, interpolations, left and right handle types, group)}
    bag = anim_utils.action_get_channelbag_for_slot(action, action.slots[0])
    out = {}
    for c in bag.fcurves:
        k = c.keyframe_points
        co = np.empty(2 * len(k), np.float32); k.foreach_get("co", co)
        out[(c.data_path, c.array_index)] = (
            co[0::2], co[1::2], sorted({p.interpolation for p in k}),
            sorted({(p.handle_left_type, p.handle_right_type) for p in k}), c.group.name if c.group else None)
    return out

def rotations_apart(a, theta_a, b, theta_b):
    # The largest difference between the controls' rotation matrices of two reads of the hand (each read
    # picks Euler orders of its own for quaternion and axis-angle controls, so angles alone may differ).
    ra, rb = a.rig.rotations(theta_a), b.rig.rotations(theta_b)
    return max(float(np.abs(ra[n] - rb[n]).max()) for n in rb)

def random_curve(rig, n, rng, finger=0.5, shift=0.01, turn=0.3):
    # A seeded random motion within the rig's limits: every DOF moved from the pose read, locks kept.
    step = np.where(rig.is_rotation, finger, shift)
    step[3:6] = turn
    theta = rig.start + rng.uniform(-1.0, 1.0, (n, rig.n_dofs)) * step
    return rig.clip(np.where(rig.locked, rig.start, theta))

def playback(hand_obj, faces, posed, theta, frames):
    # Write the action, play it back frame by frame, and compare with apply_pose keying the same poses one
    # frame after the other from the same start (the oracle); returns the measures.
    armature = posed.armature_object()
    start = channels(armature)
    action = retarget_action.write_action(posed, theta, frames, "Retargeted")
    written = table(action)
    shown, back, skin, deformed = [], [], [], []
    for f, frame in enumerate(frames):
        scene.frame_set(int(frame))
        shown.append(channels(armature))
        again = bridge.posed_hand(hand_obj, faces)
        back.append(rotations_apart(again, again.start, posed, theta[f]))
        ours = posed.skin.posed_vertices(theta[f])
        skin.append(float(np.abs(again.skin.posed_vertices(again.start) - ours).max()))
        deformed.append(bridge.deviation(posed, theta[f]))
    assigned = armature.animation_data.action == action
    armature.animation_data.action = None
    set_channels(armature, start)
    oracle = []
    for f, frame in enumerate(frames):
        bridge.apply_pose(posed, theta[f], int(frame))
        oracle.append(channels(armature))
    keyed = table(armature.animation_data.action)
    names = sorted(shown[0])
    differ = max(float(np.abs(a[n] - b[n]).max()) for a, b in zip(shown, oracle) for n in names)
    curves = sorted(written) == sorted(keyed)
    key_values = max(float(np.abs(written[c][1] - keyed[c][1]).max()) for c in written) if curves else None
    same_frames = curves and all(np.array_equal(written[c][0], keyed[c][0]) for c in written)
    same_settings = curves and all(written[c][2:] == keyed[c][2:] for c in written)
    bones = sorted({path.split('"')[1] for path, _ in written})
    return dict(assigned=assigned, action=action.name, differ=differ, curves=curves, n_curves=len(written),
                key_values=key_values, same_frames=same_frames, same_settings=same_settings,
                settings=[list(map(list, written[c][2:4])) for c in list(written)[:1]],
                keys=sorted({len(v[0]) for v in written.values()}), bones=bones,
                frames=written[next(iter(written))][0].tolist(),
                back=max(back), skin=max(skin), deformed=max(deformed),
                controls=list(posed.rig.names), root=posed.rig.plan.root,
                modes={n: armature.pose.bones[n].rotation_mode for n in posed.rig.names})
"""

MIXED = {"forearm": "QUATERNION", "index_1": "QUATERNION", "middle_2": "AXIS_ANGLE", "ring_1": "ZXY"}


@pytest.mark.parametrize("modes", [None, MIXED], ids=["euler", "mixed-modes"])
def test_the_action_plays_back_what_apply_pose_keys(modes, tmp_path):
    """Oracle: the written action, played back, shows at every keyed frame the channel values apply_pose
    sets for that frame's pose (keying frame after frame from the same start); its F-curves are the ones
    apply_pose keys, with the same frames, values, interpolation and handles; and the pose it shows reads
    back as θ, deforming the skin as the solver does."""
    out = run_blender(
        f"""
        hand_obj, faces, posed = procedural_hand({modes!r})
        theta = random_curve(posed.rig, 30, np.random.default_rng(5))
        result(playback(hand_obj, faces, posed, theta, np.arange(30) * 2 + 11))
        """,
        tmp_path,
        setup=SETUP,
    )
    assert out["assigned"] and out["action"] == "Retargeted"
    assert out["curves"] and out["same_frames"] and out["same_settings"]
    assert out["frames"] == list(range(11, 71, 2)) and out["keys"] == [30]
    assert out["settings"] == [[["BEZIER"], [["AUTO_CLAMPED", "AUTO_CLAMPED"]]]]
    assert out["key_values"] <= 1e-6 and out["differ"] <= 1e-6  # float32 storage of the same values
    # Root location (3) and rotation, three angles or four numbers per control.
    rotation = {"QUATERNION": 4, "AXIS_ANGLE": 4}
    expected = 3 + sum(rotation.get(m, 3) for m in out["modes"].values())
    assert out["n_curves"] == expected and out["bones"] == sorted(out["controls"])
    if modes:
        assert all(out["modes"][n] == m for n, m in modes.items())
    assert out["back"] < 1e-5  # the controls read back as θ's rotations
    assert out["skin"] < 1e-6 and out["deformed"] < 1e-5  # the root too; Blender's skin is the solver's


def test_the_action_keys_the_rigify_controls(tmp_path):
    """The same on a generated Rigify rig: the keys are on its FK controls (no DEF or MCH bone), and the
    pose played back deforms the hand as the solver's pose through every constraint and B-Bone."""
    out = run_blender(
        """
        from contact_edit_addon.assets import rigify
        hand, rig = rigify.rigify_hand(scene.collection)
        rig.pose.bones["upper_arm_parent.R"]["IK_FK"] = 1.0  # the arm follows the FK chain
        rig.update_tag(); bpy.context.view_layer.update()
        faces = bridge.trimesh(hand).faces
        posed = bridge.posed_hand(hand, faces)
        theta = random_curve(posed.rig, 8, np.random.default_rng(3), finger=0.4, shift=0.01, turn=0.2)
        result(playback(hand, faces, posed, theta, np.arange(1, 9)))
        """,
        tmp_path,
        setup=SETUP,
        timeout=900,
    )
    assert out["root"] == "hand_fk.R"
    assert out["curves"] and out["same_frames"] and out["same_settings"]
    assert out["key_values"] <= 1e-6 and out["differ"] <= 1e-6
    assert out["bones"] == sorted(out["controls"]) and len(out["bones"]) > 10
    assert not [b for b in out["bones"] if b.startswith(("DEF-", "MCH-", "ORG-"))]
    assert out["back"] < 1e-5 and out["skin"] < 1e-6 and out["deformed"] < 1e-5


def test_quaternion_keys_never_flip_sign(tmp_path):
    """A finger control turned on through ±π and a root turned on through a half turn: their quaternions
    as converted flip sign between frames, the keys do not, and playback between keys stays a rotation
    (interpolating q to -q would pass near zero) and reads back as θ."""
    out = run_blender(
        """
        hand_obj, faces, posed = procedural_hand({"forearm": "QUATERNION", "index_1": "QUATERNION"})
        rig = posed.rig
        n = 24
        theta = np.tile(rig.start, (n, 1))
        b = rig.bone_index("index_1")
        x = 2.5 + 0.06 * np.arange(n)
        theta[:, rig.rotation_dof(b, 0)] = np.where(x > np.pi, x - 2 * np.pi, x)  # wraps from π to -π
        axis = np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0)
        theta[:, 3:6] = (2.7 + 0.04 * np.arange(n))[:, None] * axis  # through a half turn
        raw_finger = np.array([tuple(Euler(t, rig.orders[b]).to_quaternion())
                               for t in theta[:, rig.rotation_dof(b, 0):rig.rotation_dof(b, 0) + 3]])
        raw_root = np.array([tuple(Matrix(rig.root_transform(t)[:3, :3]).to_quaternion()) for t in theta])
        action = retarget_action.write_action(posed, theta, range(1, n + 1), "Turns")
        bag = anim_utils.action_get_channelbag_for_slot(action, action.slots[0])
        def keys(bone):
            q = np.zeros((n, 4))
            for c in bag.fcurves:
                if c.data_path == f'pose.bones["{bone}"].rotation_quaternion':
                    co = np.empty(2 * n, np.float32); c.keyframe_points.foreach_get("co", co)
                    q[:, c.array_index] = co[1::2]
            return q
        def dots(q):
            return np.einsum("fi,fi->f", q[1:], q[:-1])
        armature = posed.armature_object()
        norms, back, deformed = [], [], []
        for f in range(1, n):
            scene.frame_set(f, subframe=0.5)
            bones = armature.pose.bones
            norms.append(min(np.linalg.norm(bones[k].rotation_quaternion) for k in ("forearm", "index_1")))
            scene.frame_set(f)
            again = bridge.posed_hand(hand_obj, faces)
            back.append(rotations_apart(again, again.start, posed, theta[f - 1]))
            deformed.append(bridge.deviation(posed, theta[f - 1]))
        result(dict(raw_finger=float(dots(raw_finger).min()), raw_root=float(dots(raw_root).min()),
                    finger=float(dots(keys("index_1")).min()), root=float(dots(keys("forearm")).min()),
                    norms=float(min(norms)), back=max(back), deformed=max(deformed)))
        """,
        tmp_path,
        setup=SETUP,
    )
    assert out["raw_finger"] < -0.9 and out["raw_root"] < -0.9  # as converted, they flip
    assert out["finger"] > 0.9 and out["root"] > 0.9  # as keyed, consecutive keys are near
    assert out["norms"] > 0.99
    assert out["back"] < 1e-5 and out["deformed"] < 1e-5


def test_writing_a_thousand_frames_beats_keying_them_one_by_one(tmp_path):
    """Measured, not timed: write_action of 1,000 frames against apply_pose keying each frame; the two
    actions hold the same keys. Prints the medians of three runs (pytest -s)."""
    out = run_blender(
        """
        hand_obj, faces, posed = procedural_hand()
        armature = posed.armature_object()
        n = 1000
        theta = random_curve(posed.rig, n, np.random.default_rng(1))
        start = channels(armature)
        ours, theirs = [], []
        for run in range(3):
            set_channels(armature, start)
            t = time.perf_counter()
            action = retarget_action.write_action(posed, theta, range(1, n + 1), "Fast", replace=True)
            ours.append(time.perf_counter() - t)
            armature.animation_data.action = None
            set_channels(armature, start)
            t = time.perf_counter()
            for f in range(n):
                bridge.apply_pose(posed, theta[f], f + 1)
            theirs.append(time.perf_counter() - t)
            keyed = armature.animation_data.action
            armature.animation_data.action = None
        a, b = table(action), table(keyed)
        same = sorted(a) == sorted(b)
        result(dict(ours=float(np.median(ours)), theirs=float(np.median(theirs)), same=same,
                    differ=max(float(np.abs(a[c][1] - b[c][1]).max()) for c in a) if same else None,
                    curves=len(a), bones=len(posed.rig.names)))
        """,
        tmp_path,
        setup=SETUP,
    )
    print(
        f"\n1000 frames x {out['bones']} controls ({out['curves']} F-curves): write_action "
        f"{out['ours'] * 1e3:.0f} ms, apply_pose per frame {out['theirs'] * 1e3:.0f} ms "
        f"({out['theirs'] / out['ours']:.0f}x)"
    )
    assert out["same"] and out["differ"] <= 1e-6


def png_size(path) -> tuple[int, int]:
    """(width, height) from a PNG's IHDR chunk."""
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def test_the_metrics_plot_is_packed_and_survives_reopening(tmp_path):
    """The image has the PNG's size and colour, is packed, replaces an image of the same name (whatever
    showed that one shows the new one), and is still there, with its pixels, after saving, deleting the
    PNG and reopening the .blend in a fresh process."""
    matplotlib = pytest.importorskip("matplotlib")
    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    first, second = tmp_path / "first.png", tmp_path / "metrics.png"
    for path, size, colour in ((first, (2, 1), "blue"), (second, (4, 3), "red")):
        figure = plt.figure(figsize=size, dpi=40, facecolor=colour)
        figure.savefig(path, facecolor=colour)
        plt.close(figure)
    width, height = png_size(second)
    assert (width, height) == (160, 120) and png_size(first) == (80, 40)
    blend = tmp_path / "with_plot.blend"
    out = run_blender(
        f"""
        old = retarget_action.metrics_image({str(first)!r}, "Retarget metrics")
        texture = bpy.data.textures.new("Shows the plot", "IMAGE")
        texture.image = old
        texture.use_fake_user = True
        image = retarget_action.metrics_image({str(second)!r}, "Retarget metrics")
        names = sorted(i.name for i in bpy.data.images)
        shown = texture.image.name, tuple(texture.image.size)
        errors = {{}}
        bad = {{"missing": {str(tmp_path / "nothing.png")!r}, "not a png": {str(blend)!r} + ".txt"}}
        for key, path in bad.items():
            if key == "not a png":
                open(path, "w").write("not an image")
            try:
                retarget_action.metrics_image(path, "Retarget metrics")
            except BridgeError as err:
                errors[key] = str(err)
        bpy.ops.wm.save_as_mainfile(filepath={str(blend)!r})
        result(dict(names=names, size=list(image.size), packed=image.packed_file is not None, shown=shown,
                    errors=errors, after=sorted(i.name for i in bpy.data.images)))
        """,
        tmp_path,
        setup=SETUP,
    )
    assert out["names"] == ["Retarget metrics"] and out["after"] == ["Retarget metrics"]
    assert out["size"] == [width, height] and out["packed"]
    assert out["shown"] == ["Retarget metrics", [width, height]]
    assert "no metrics plot" in out["errors"]["missing"] and "nothing.png" in out["errors"]["missing"]
    assert "no image Blender can read" in out["errors"]["not a png"]
    first.unlink()
    second.unlink()
    again = run_blender(
        f"""
        bpy.ops.wm.open_mainfile(filepath={str(blend)!r})
        image = bpy.data.images.get("Retarget metrics")
        pixels = np.empty(4 * image.size[0] * image.size[1], np.float32)
        image.pixels.foreach_get(pixels)
        result(dict(size=list(image.size), packed=image.packed_file is not None,
                    mean=pixels.reshape(-1, 4).mean(axis=0).tolist()))
        """,
        tmp_path,
        setup="import numpy as np\n",
    )
    assert again["size"] == [width, height] and again["packed"]
    assert again["mean"] == pytest.approx([1.0, 0.0, 0.0, 1.0], abs=0.02)  # the red plot


def test_bad_input_is_refused_by_name_and_changes_nothing(tmp_path):
    """Theta of the wrong width or with NaN, a frame count that is not theta's, frames out of order, an
    armature that already has an action: each a BridgeError saying what is wrong, and no action made.
    With replace=True the old action gives way but is kept."""
    out = run_blender(
        """
        hand_obj, faces, posed = procedural_hand()
        rig = posed.rig
        armature = posed.armature_object()
        theta = random_curve(rig, 5, np.random.default_rng(2))
        nan = theta.copy(); nan[3, rig.rotation_dof(rig.bone_index("thumb_2"), 1)] = np.nan
        cases = {
            "width": (theta[:, :-1], range(5)),
            "one pose": (theta[0], range(1)),
            "nan": (nan, range(5)),
            "count": (theta, range(4)),
            "order": (theta, [1, 2, 4, 3, 5]),
        }
        errors = {}
        for key, (t, frames) in cases.items():
            try:
                retarget_action.write_action(posed, t, frames, "Bad")
            except BridgeError as err:
                errors[key] = str(err)
        made = [a.name for a in bpy.data.actions]
        first = retarget_action.write_action(posed, theta, range(5), "First")
        try:
            retarget_action.write_action(posed, theta, range(5), "Second")
        except BridgeError as err:
            errors["taken"] = str(err)
        kept = [a.name for a in bpy.data.actions], armature.animation_data.action.name
        second = retarget_action.write_action(posed, theta, range(5), "Second", replace=True)
        result(dict(errors=errors, made=made, kept=kept, now=armature.animation_data.action.name,
                    first=[first.users, first.use_fake_user], d=rig.n_dofs))
        """,
        tmp_path,
        setup=SETUP,
    )
    errors, d = out["errors"], out["d"]
    assert f"(frames, {d})" in errors["width"] and f"({5}, {d - 1})" in errors["width"]
    assert f"(frames, {d})" in errors["one pose"]
    assert "not finite" in errors["nan"] and "thumb_2.rotation.y" in errors["nan"]
    assert "first: 3" in errors["nan"]
    assert "5 poses but 4 frames" in errors["count"]
    assert "frames must increase" in errors["order"] and "row 3" in errors["order"]
    assert out["made"] == []
    assert "already has the action 'First'" in errors["taken"] and "replace=True" in errors["taken"]
    assert out["kept"] == [["First"], "First"]
    assert out["now"] == "Second" and out["first"] == [1, True]  # kept by its fake user
