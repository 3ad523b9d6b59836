"""Retargeting inside Blender (contact_edit_addon.retarget.scene) in the real bpy module.

The source: the procedural human hand's armature keyed over 120 frames, holding a mug that it lifts and
turns (:mod:`tests.held_mug`). The target: the procedural alien hand (three fingers), a second armature
placed elsewhere, turned and scaled by 1.25 (the hand inside it built at 0.8, so that it is life-size in
the world), so that the motion must be carried into its space. The result is an
action on the alien's armature; played back by Blender, its own evaluated skin must meet the mug where
the transferred contacts say, as near as the retargeting measured and within the CLI's bar (1.5 % of
the hand's length); a run stopped part way changes nothing, and the next one goes on from its frames.

Then the same grasp, 24 frames of it, onto the rig animators pose: a Rigify human whose right hand is the
procedural human hand (contact_edit_addon.assets.rigify). The action must key only Rigify's controls (the
hand's IK control, the palm and finger controls), and Blender's own evaluation of the rig, through its IK,
constraints and B-Bones, must put the contacts where the retargeting measured them.
"""

from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest

from geodesics import SurfacePoints, TriMesh
from solver import objects
from solver.hands import make_hand

from .blender import run_blender
from .held_mug import MUG_HEIGHT, MUG_RADIUS, scene_script

pytestmark = [
    pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="needs bpy (the dev extra)"),
    pytest.mark.slow,
]

KEYS = (1, 30, 50, 70, 100, 120)  # held_mug's keys, stretched over 120 frames
FIRST, LAST = 1, 120
CHECK = (1, 40, 60, 85, 110, 120)  # frames played back in Blender
SCALE = 1.25  # the alien armature's (uniform) scale
BAR = 0.015  # of the target hand's length: tests/test_retarget_pipeline.py's bar

SCRIPT = """
import os
import pathlib
import time
from contact_edit_addon.retarget import scene as scene_retarget
from mathutils import Matrix, Euler
alien = hands.make_hand("alien", 1 / {scale})  # life-size in the world, inside the scaled armature
alien_obj, alien_rig = assets.hand_objects(alien, "Alien", scene.collection)
alien_rig.matrix_world = Matrix.Translation((0.6, 0.2, 0.0)) @ Euler((0.3, 0.0, 1.2)).to_matrix().to_4x4() @ (
    Matrix.Scale({scale}, 4))

class Stop(Exception):
    pass

def stop_after(n):  # stops as Esc does: from the progress callback, after n frames' full poses
    def progress(stage, done, total):
        if stage == "full" and done >= n:
            raise Stop
    return progress

try:
    scene_retarget.retarget_scene(scene, hand_obj, mug, alien_obj, {first}, {last}, folder={folder!r},
                                  workers=2, progress=stop_after(40))
except Stop:
    pass
stopped_action = alien_rig.animation_data is not None and alien_rig.animation_data.action is not None
full = list(pathlib.Path({folder!r}).glob("*/frames/full/*.npz"))
kept = {{str(p): p.stat().st_mtime_ns for p in full}}
calls = []
def progress(stage, done, total):
    calls.append((stage, done, total))
t = time.perf_counter()
outcome = scene_retarget.retarget_scene(scene, hand_obj, mug, alien_obj, {first}, {last}, folder={folder!r},
                                        workers=2, progress=progress)
seconds = time.perf_counter() - t
current = scene.frame_current
r = outcome.result
action = alien_rig.animation_data.action
frames = keyed_frames(alien_rig)
from bpy_extras import anim_utils
bag = anim_utils.action_get_channelbag_for_slot(action, alien_rig.animation_data.action_slot)
metric = bag.fcurves.find('["retarget_contacts_mm"]')
metric_keys = [k.co[0] for k in metric.keyframe_points]
metric_values = [metric.evaluate(f) for f in range({first}, {last} + 1)]
out = {{}}
for f in {check}:
    out[f"alien_{{f}}"] = blender_world(alien_obj, f)
    out[f"mug_{{f}}"] = blender_world(mug, f)
c = r.transferred
np.savez({arrays!r}, hand_faces=c.hand_contacts.faces, hand_bary=c.hand_contacts.bary,
         hand_offsets=c.hand_contacts.offsets, object_faces=c.object_contacts.faces,
         object_bary=c.object_contacts.bary, object_offsets=c.object_contacts.offsets,
         contact_distance=r.contact_distance, estimate=r.estimate_contact_distance, theta=r.theta, **out)
stored = list((outcome.folder / "frames" / "full").glob("*.npz"))
result({{"seconds": seconds, "stages": sorted({{s for s, _, _ in calls}}), "action": action.name,
         "frames": frames, "scale": outcome.scale, "stopped_action": stopped_action, "kept": len(kept),
         "stored": len(stored), "resolved": sorted(p for p, t in kept.items() if os.stat(p).st_mtime_ns != t),
         "summary": outcome.summary(), "current": current, "warnings": list(r.warnings),
         "full_calls": [d for s, d, _ in calls if s == "full"], "metric_keys": metric_keys,
         "metric_values": metric_values, "metric_group": metric.group.name,
         "metric_description": alien_rig.id_properties_ui("retarget_contacts_mm").as_dict()["description"]}})
"""


@pytest.fixture(scope="module")
def retargeted(tmp_path_factory):
    folder = tmp_path_factory.mktemp("scene-retarget")
    arrays = folder / "arrays.npz"
    script = SCRIPT.format(
        scale=SCALE, first=FIRST, last=LAST, check=CHECK, folder=str(folder / "runs"), arrays=str(arrays)
    )
    out = run_blender(script, folder, setup=scene_script(KEYS), timeout=1800)
    out["arrays"] = dict(np.load(arrays))
    print(f"\nretargeted {LAST - FIRST + 1} frames in {out['seconds']:.1f} s: {out['summary']}")
    return out


def _contacts(arrays, side, frame) -> SurfacePoints:
    offsets = arrays[f"{side}_offsets"]
    rows = slice(offsets[frame], offsets[frame + 1])
    return SurfacePoints(arrays[f"{side}_faces"][rows], arrays[f"{side}_bary"][rows])


def test_the_action_keys_every_frame_and_the_scene_is_restored(retargeted):
    assert retargeted["action"] == "Alien from Hand"
    assert retargeted["frames"] == list(range(FIRST, LAST + 1))
    assert {"read", "contacts", "transfer", "root", "full", "refine", "metrics"} <= set(retargeted["stages"])
    assert retargeted["current"] == 7  # held_mug leaves the scene on frame 7: read and put back
    assert retargeted["scale"] == pytest.approx(SCALE, rel=1e-6)


def test_blender_plays_back_what_was_solved_and_the_contacts_meet_the_mug(retargeted):
    """Blender's own skin of the alien at the keyed pose: the transferred contacts' mean distance to their
    object points is what the retargeting measured (in its space, times the armature's scale), and its
    median over the contact frames is within the bar."""
    arrays = retargeted["arrays"]
    alien = make_hand("alien", 1 / SCALE)  # in the armature's space
    measured = arrays["contact_distance"] * SCALE
    played = []
    for f in CHECK:
        i = f - FIRST
        hand = _contacts(arrays, "hand", i)
        if len(hand) == 0:
            assert np.isnan(measured[i])
            continue
        skin = TriMesh(arrays[f"alien_{f}"].astype(np.float64), alien.mesh.faces)
        mug_world = arrays[f"mug_{f}"].astype(np.float64)
        obj = _contacts(arrays, "object", i)
        corners = mug_world[_mug_faces(mug_world)[obj.faces]]
        O = np.einsum("kj,kjd->kd", obj.bary, corners)
        gap = np.linalg.norm(hand.positions(skin) - O, axis=1).mean()
        played.append(gap)
        assert gap == pytest.approx(measured[i], rel=1e-3, abs=2e-5)  # float32 meshes in Blender
    assert len(played) >= 4
    contact = np.nanmedian(measured)
    bar = BAR * make_hand("alien").length
    print(f"\nmedian contact distance {contact * 1e3:.2f} mm (bar {bar * 1e3:.2f} mm)")
    assert contact <= bar


def _mug_faces(vertices) -> np.ndarray:
    mug = objects.mug(radius=MUG_RADIUS, height=MUG_HEIGHT)
    assert len(vertices) == mug.n_vertices
    return mug.faces


def test_a_stopped_retarget_changes_nothing_and_the_next_goes_on_from_its_frames(retargeted):
    """Stopped from its progress callback (as Esc stops the operator) after 40 frames' full poses: no
    action; run again on the same inputs, it solves only the other frames."""
    assert not retargeted["stopped_action"]
    assert 40 <= retargeted["kept"] < LAST - FIRST + 1
    assert retargeted["stored"] == LAST - FIRST + 1
    assert retargeted["resolved"] == []  # the kept frames were not solved again
    assert retargeted["full_calls"][0] == retargeted["kept"]  # progress starts from the kept frames


def test_summary_says_how_near_and_warns_in_words(retargeted):
    summary = retargeted["summary"]
    assert summary.startswith("Retargeted 120 frames; contacts ")
    for warning in retargeted["warnings"]:
        assert warning in summary
    json.dumps(retargeted["warnings"])


def test_the_metrics_are_keyed_beside_the_motion(retargeted):
    """Each frame's contact distance (mm) is a key of the armature's custom property in the same action
    (the Graph Editor plots it with no plotting library), at the frames that have contacts."""
    d = retargeted["arrays"]["contact_distance"] * retargeted["scale"] * 1e3
    has = np.isfinite(d)
    assert retargeted["metric_keys"] == [float(f) for f in np.arange(FIRST, LAST + 1)[has]]
    np.testing.assert_allclose(np.array(retargeted["metric_values"])[has], d[has], rtol=1e-6)
    assert retargeted["metric_group"] == "Retarget metrics"
    assert "transferred contacts" in retargeted["metric_description"]


RIGIFY_KEYS = (1, 8, 12, 16, 20, 24)  # held_mug's keys, squeezed into 24 frames
RIGIFY_CHECK = (1, 12, 18, 24)

RIGIFY = """
from contact_edit_addon.assets import rigify
from contact_edit_addon.retarget import scene as scene_retarget
from bpy_extras import anim_utils
target, rig = rigify.rigify_hand(scene.collection)
outcome = scene_retarget.retarget_scene(scene, hand_obj, mug, target, 1, 24, folder={folder!r}, workers=2)
data = rig.animation_data
bag = anim_utils.action_get_channelbag_for_slot(data.action, data.action_slot)
bones = [curve.data_path for curve in bag.fcurves if curve.data_path.startswith("pose.")]  # not the metrics
keyed = sorted({{path.split('"')[1] for path in bones}})
out = {{}}
for f in {check}:
    out[f"target_{{f}}"] = blender_world(target, f)
    out[f"mug_{{f}}"] = blender_world(mug, f)
r = outcome.result
c = r.transferred
np.savez({arrays!r}, hand_faces=c.hand_contacts.faces, hand_bary=c.hand_contacts.bary,
         hand_offsets=c.hand_contacts.offsets, object_faces=c.object_contacts.faces,
         object_bary=c.object_contacts.bary, object_offsets=c.object_contacts.offsets,
         contact_distance=r.contact_distance, **out)
result({{"keyed": keyed, "bones": [b.name for b in rig.pose.bones], "summary": outcome.summary(),
         "scale": outcome.scale}})
"""


@pytest.fixture(scope="module")
def rigify_retargeted(tmp_path_factory):
    folder = tmp_path_factory.mktemp("scene-retarget-rigify")
    arrays = folder / "arrays.npz"
    script = RIGIFY.format(folder=str(folder / "runs"), check=RIGIFY_CHECK, arrays=str(arrays))
    out = run_blender(script, folder, setup=scene_script(RIGIFY_KEYS), timeout=1800)
    out["arrays"] = dict(np.load(arrays))
    print(f"\nonto Rigify: {out['summary']}")
    return out


def test_onto_rigify_the_action_keys_its_controls_only(rigify_retargeted):
    keyed = rigify_retargeted["keyed"]
    assert set(keyed) <= set(rigify_retargeted["bones"])
    assert not [name for name in keyed if name.startswith(("DEF-", "ORG-", "MCH-"))]
    assert "hand_ik.R" in keyed  # the wrist follows the hand's IK control, as an animator keys it
    fingers = ("thumb", "f_index", "f_middle", "f_ring", "f_pinky")
    assert all(any(name.startswith(f) for name in keyed) for f in fingers)


def test_blender_plays_the_rigify_action_back_as_solved(rigify_retargeted):
    """Blender's evaluated Rigify hand at the keyed frames: each frame's transferred contacts lie as far
    from their mug points as the retargeting measured, to within how closely Blender's iterative IK
    reaches the hand's IK control (a tenth of a millimetre or so: tests/test_addon_rigify.py), and the
    median is within the bar."""
    arrays = rigify_retargeted["arrays"]
    human = make_hand("human")
    measured = arrays["contact_distance"] * rigify_retargeted["scale"]
    played = 0
    for f in RIGIFY_CHECK:
        i = f - 1
        hand = _contacts(arrays, "hand", i)
        if len(hand) == 0:
            continue
        skin = TriMesh(arrays[f"target_{f}"].astype(np.float64), human.mesh.faces)
        mug_world = arrays[f"mug_{f}"].astype(np.float64)
        obj = _contacts(arrays, "object", i)
        O = np.einsum("kj,kjd->kd", obj.bary, mug_world[_mug_faces(mug_world)[obj.faces]])
        gap = np.linalg.norm(hand.positions(skin) - O, axis=1).mean()
        print(f"frame {f}: played back {gap * 1e3:.3f} mm, measured {measured[i] * 1e3:.3f} mm")
        assert abs(gap - measured[i]) < 5e-4
        played += 1
    assert played >= 3
    assert np.nanmedian(measured) <= BAR * human.length


ANNOTATION_FILES = """
import json
from contact_edit_addon import bridge
from contact_edit_addon.retarget import scene as scene_retarget
from contact_edit_addon.bridge import BridgeError
from solver.retarget.annotate import default_annotation, procedural_hand
alien_obj, _ = assets.hand_objects(hands.make_hand("alien"), "Alien", scene.collection)
witch_obj, _ = assets.hand_objects(hands.make_hand("witch"), "Witch", scene.collection)
bpy.ops.mesh.primitive_uv_sphere_add(radius=0.05)
sphere = bpy.context.object
reader = scene_retarget.prepare(scene, hand_obj, mug, alien_obj, 1, 6, folder={folder!r})[0]
source = procedural_hand(reader.hand_rest)

def written(target_obj, name):
    path = {folder!r} + "/" + name
    default_annotation(source, procedural_hand(bridge.trimesh(target_obj))).save(path)
    return path

def message(target_obj, path):
    try:
        job = scene_retarget.prepare(scene, hand_obj, mug, target_obj, 1, 6, annotation_path=path,
                                     folder={folder!r})[1]
    except BridgeError as err:
        return str(err)
    return job.annotation.to_dict()

for_alien, for_witch = written(alien_obj, "alien.json"), written(witch_obj, "witch.json")
broken = {folder!r} + "/broken.json"
with open(broken, "w") as out:
    out.write(open(for_alien).read()[:500])
result({{"read": message(alien_obj, for_alien) == json.load(open(for_alien)),
         "other_hands": message(alien_obj, for_witch), "broken": message(alien_obj, broken),
         "missing": message(alien_obj, {folder!r} + "/none.json"), "not_procedural": message(sphere, "")}})
"""


def test_an_annotation_file_is_read_and_bad_ones_are_named(tmp_path):
    """Hands other than the procedural ones retarget with an annotation.json (the CLI writes one): the
    Retarget inputs read it for the scene's hands, and refuse, saying why, a file made for other hands,
    a missing or broken one, and no file for a hand that has no built-in annotation."""
    script = ANNOTATION_FILES.format(folder=str(tmp_path))
    out = run_blender(script, tmp_path, setup=scene_script(KEYS), timeout=600)
    print("\n".join(str(out[k]) for k in ("other_hands", "missing", "broken", "not_procedural")))
    assert out["read"] is True  # the job carries the file's annotation, unchanged
    assert "witch.json" in out["other_hands"] and "made for another hand" in out["other_hands"]
    assert out["other_hands"].endswith("(retargeting 'Hand' onto 'Alien')")
    assert "none.json" in out["missing"]
    assert "broken.json" in out["broken"]
    assert "'Sphere' is not one of the procedural hands" in out["not_procedural"]
    assert "annotation file made for these two hands" in out["not_procedural"]
