"""Blender parity: the rig and skin reproduce Blender's own armature deformation (the real bpy module,
in a fresh process; skipped where bpy is not installed). The armature is built by the add-on's
``assets.hand_objects``: bones from the rig's heads, tails and rolls, weights as vertex groups."""

import importlib.util

import pytest

from .blender import run_blender

pytestmark = pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="needs bpy (the dev extra)")

SCRIPT = """
import numpy as np
from contact_edit_addon import assets
from solver import hands

hand = hands.make_hand("human")
rig = hand.rig
bpy.ops.wm.read_factory_settings(use_empty=True)
obj, armature = assets.hand_objects(hand, "hand", bpy.context.scene.collection)
rest = np.array([np.array(armature.data.bones[n].matrix_local) for n in rig.names])
rng = np.random.default_rng(0)
out = {"rest": float(np.abs(rest - rig.matrix_local).max()), "pose": 0.0, "vertices": 0.0, "size": hand.size}
for trial in range(3):
    theta = np.zeros(rig.n_dofs)
    joints = rig.dof_bone != 0
    theta[joints] = rng.uniform(rig.lower[joints], rig.upper[joints])
    theta[:3], theta[3:6] = rng.uniform(-0.05, 0.05, 3), rng.uniform(-1, 1, 3)
    for b, name in enumerate(rig.names):
        pose_bone = armature.pose.bones[name]
        pose_bone.rotation_mode = rig.rotation_modes[b]
        pose_bone.rotation_euler = tuple(theta[3 + 3 * b : 6 + 3 * b])
        if b == 0:
            pose_bone.location = tuple(theta[:3])
    bpy.context.view_layer.update()
    matrices = np.array([np.array(armature.pose.bones[n].matrix) for n in rig.names])
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    deformed = np.array([v.co[:] for v in evaluated.to_mesh().vertices])
    evaluated.to_mesh_clear()
    out["pose"] = max(out["pose"], float(np.abs(matrices - rig.pose_matrices(theta)).max()))
    out["vertices"] = max(out["vertices"], float(np.abs(deformed - hand.posed_vertices(theta)).max()))
result(out)
"""


def test_poses_and_skinning_match_blenders_armature_modifier(tmp_path):
    found = run_blender(SCRIPT, tmp_path)
    # Blender computes in float32: agreement to its precision, on a hand about 0.3 m across.
    assert found["rest"] < 1e-6
    assert found["pose"] < 1e-6
    assert found["vertices"] < 1e-6 * found["size"]
