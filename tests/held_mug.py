"""A scene for the retargeting's Blender tests, built in the bpy module: the procedural human hand (an
armature and a skinned mesh, as *Add › Contact Edit* makes them) and a mug scaled (1.5, 1.5, 1.2), keyed
linearly: the open hand approaches the mug, closes on it (the flex-to-contact grasp), lifts it by 8 cm while
the mug turns about its axis, and presses the fingers 0.08 rad deeper in. ``blender_world(obj, frame)``
gives Blender's own evaluated mesh in world space.
"""

MUG_RADIUS, MUG_HEIGHT = 0.04, 0.095  # contact_edit_addon.assets' example mug
MUG_SCALE = (1.5, 1.5, 1.2)
WHERE = (0.1, -0.2, 0.05)
LIFT = (0.0, 0.0, 0.08)
TURN = 0.5  # radians about the mug's axis, between the fourth and the sixth key
FPS = 30 / 1.001

KEYS = (1, 15, 25, 35, 50, 60)


def scene_script(keys=KEYS) -> str:
    """The scene, built in bpy: the hand keyed at ``keys`` (six frames: open and back, open at the mug,
    closed, still closed, lifted, pressed deeper), the mug turning between the fourth and the sixth."""
    k = keys
    return f"""
import numpy as np
from mathutils import Matrix
from geodesics import TriMesh
from solver import hands, objects
from solver.grasp import grasp, placement
from contact_edit_addon import assets
from contact_edit_addon.bridge import BridgeError
from contact_edit_addon.retarget import motion as scene_motion
from solver.retarget import detection

bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
scene.render.fps, scene.render.fps_base = 30, 1.001
hand = hands.make_hand("human")
rig = hand.rig
hand_obj, armature = assets.hand_objects(hand, "Hand", scene.collection)
MUG_SCALE, WHERE, LIFT = np.array({MUG_SCALE}), np.array({WHERE}), np.array({LIFT})
mug_mesh = objects.mug(radius={MUG_RADIUS}, height={MUG_HEIGHT})
scaled = TriMesh(mug_mesh.vertices * MUG_SCALE, mug_mesh.faces)
mug = assets.mesh_object("Mug", mug_mesh, scene.collection)
place = np.eye(4)
place[:3, 3] = WHERE
place = place @ placement(hand, scaled, assets.PALM_GAP)
armature.matrix_world = Matrix(place)
mug.location, mug.scale = WHERE, MUG_SCALE
inverse = np.linalg.inv(place)
in_hand = TriMesh((scaled.vertices + WHERE) @ inverse[:3, :3].T + inverse[:3, 3], scaled.faces)
closed = grasp(hand, in_hand, rig.rest).theta
deeper = closed.copy()
fingers = (rig.dof_bone > 1) & (np.arange(rig.n_dofs) % 3 == 0)  # every finger bone's x (flexion)
deeper[fingers] = np.minimum(closed[fingers] + 0.08, rig.upper[fingers])
# A world displacement d of the hand is the root bone's location (R_world R_rest)^T d.
to_root = (place[:3, :3] @ rig.matrix_local[0, :3, :3]).T
BACK = np.array([-0.05, 0.0, 0.0])
KEYS = {{{k[0]}: (BACK, rig.rest), {k[1]}: (0 * BACK, rig.rest), {k[2]}: (0 * BACK, closed),
        {k[3]}: (0 * BACK, closed), {k[4]}: (LIFT, closed), {k[5]}: (LIFT, deeper)}}
for frame, (offset, theta) in KEYS.items():
    for b, name in enumerate(rig.names):
        pose_bone = armature.pose.bones[name]
        if b == 0:
            pose_bone.location = tuple(to_root @ offset)
            pose_bone.keyframe_insert("location", frame=frame)
        else:
            pose_bone.rotation_euler = tuple(theta[3 + 3 * b : 6 + 3 * b])
            pose_bone.keyframe_insert("rotation_euler", frame=frame)
    mug.location = tuple(WHERE + (offset if frame >= {k[3]} else 0.0))
    mug.keyframe_insert("location", frame=frame)
mug.rotation_euler = (0.0, 0.0, 0.0)
mug.keyframe_insert("rotation_euler", frame={k[3]})
mug.rotation_euler = (0.0, 0.0, {TURN})
mug.keyframe_insert("rotation_euler", frame={k[5]})
for action in bpy.data.actions:
    for layer in action.layers:
        for strip in layer.strips:
            for bag in strip.channelbags:
                for curve in bag.fcurves:
                    for key in curve.keyframe_points:
                        key.interpolation = "LINEAR"
scene.frame_set(7)

def blender_world(obj, frame):
    '''Blender's own evaluated mesh of obj at frame, transformed to world space by Blender.'''
    scene.frame_set(frame)
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    mesh = bpy.data.meshes.new_from_object(evaluated)
    mesh.transform(evaluated.matrix_world)
    co = np.empty(3 * len(mesh.vertices), np.float32)
    mesh.vertices.foreach_get("co", co)
    bpy.data.meshes.remove(mesh)
    return co.reshape(-1, 3)
"""
