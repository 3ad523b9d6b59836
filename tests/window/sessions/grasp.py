"""A person's grasp, start to end, in a real window: four pads painted by dragging the brush over the
hand, each transferred onto the mug by eye (press where it starts, drag its direction), the solve's
hotkey; then one patch on the mug turned by 45° and solved again.

Where each pad should go is a grasp known to exist (the Example's fingers wrapped around the mug by
flex-to-contact, as the demo does): that is the person's intent. The hand is opened again before any
transfer, and each pad is placed a few millimetres and degrees off where that grasp puts it, as an eye
places it."""

import math
import time

import bpy
import numpy as np
from common import addon, bridge, example
from mathutils import Matrix, Vector

from geodesics import SurfacePoints
from solver import hands

#: The pads, as a person paints them: the bone whose palm-side skin is stroked, the stroke's length and
#: the brush radius (metres on the hand).
PADS = {"index tip": ("index_3", 0.004, 0.005), "middle tip": ("middle_3", 0.004, 0.005),
        "thumb tip": ("thumb_3", 0.004, 0.005), "palm": ("hand", 0.006, 0.012)}  # fmt: skip
#: How far off an eye places a patch: its start (metres, in a random direction along the surface) and
#: its direction (up to this many radians either way).
MISPLACED, MISTURNED = 0.003, math.radians(8.0)
#: The turn of one patch on the mug before the second solve, as the rotate tool's drag gives it
#: (half a degree per pixel).
TURN, DEGREES_PER_PIXEL = 45.0, 0.5


def look_at(view, point, normal, distance: float) -> None:
    """Orbit and zoom the view as a person would, to look at ``point`` along ``-normal``."""
    view.rv3d.view_perspective = "PERSP"
    view.rv3d.view_rotation = Vector(normal).to_track_quat("Z", "Y")
    view.rv3d.view_location = Vector(point)
    view.rv3d.view_distance = distance


def pixels_per_metre(view, point) -> float:
    right = np.array(view.rv3d.view_rotation.to_matrix().col[0])
    a, b = view.project([point, np.asarray(point) + 0.01 * right])
    return float(np.linalg.norm(b - a) / 0.01)


def pad_stroke(hand, procedural, view, bone: str, length: float) -> list[tuple[float, float]]:
    """Screen points of a stroke over the middle of a bone's pad (where the demo dabs it: the palm-side
    face nearest the middle of the bone's palm-side skin, on ``procedural``, the solver's hand the
    Example's mesh was made from), along the bone by ``length`` metres."""
    face = addon("commands.demo")._pad_centre(procedural, bone)
    middle = bridge.mesh_arrays(hand.data)[0][procedural.mesh.faces[face]].mean(0)
    centre = bridge.object_to_world(hand, middle[None])[0]
    eye = np.array(view.rv3d.view_rotation.to_matrix().col[2])
    pose = hand.parent.pose.bones[bone]
    along = np.array(hand.parent.matrix_world.to_3x3() @ pose.matrix.col[1].to_3d())
    along = along - eye * (along @ eye)
    along /= np.linalg.norm(along)
    ends = view.project([centre - 0.5 * length * along, centre + 0.5 * length * along])
    return [tuple(ends[0] + (ends[1] - ends[0]) * t) for t in np.linspace(0.0, 1.0, 12)]


def on_surface(mug, mesh, location, direction) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where a pad lands as the eye sees it on the mug: the surface point nearest ``location``, the
    direction along the surface there, and the surface's normal (world)."""
    point = SurfacePoints.nearest(mesh, bridge.world_to_object(mug, location))
    on = np.einsum("kj,kjd->kd", point.bary, mesh.vertices[mesh.faces[point.faces]])
    M = np.array(mug.matrix_world)[:3, :3]
    normal = M @ mesh.face_normals[point.faces[0]]
    normal /= np.linalg.norm(normal)
    along = direction - normal * (direction @ normal)
    return bridge.object_to_world(mug, on)[0], along / np.linalg.norm(along), normal


def misplacement(mug, intent) -> dict[str, tuple[float, float]]:
    """Per transferred patch, how far (mm) its axis starts from where the grasp puts it and by how many
    degrees its direction is turned."""
    contacts, out = addon("store").load(mug), {}
    for name, (location, direction, _) in intent.items():
        axis = contacts[name].axis.points
        corners = contacts.mesh.vertices[contacts.mesh.faces[axis.faces[:2]]]
        start, second = bridge.object_to_world(mug, np.einsum("kj,kjd->kd", axis.bary[:2], corners))
        cosine = (second - start) @ direction / np.linalg.norm(second - start) / np.linalg.norm(direction)
        out[name] = (1e3 * float(np.linalg.norm(start - location)), math.degrees(math.acos(min(1.0, cosine))))
    return out


def hand_matrix(armature) -> Matrix:
    return armature.matrix_world @ armature.pose.bones["hand"].matrix


def turned_by(a: Matrix, b: Matrix) -> float:
    """Degrees between two bones' world orientations."""
    return math.degrees(a.to_quaternion().rotation_difference(b.to_quaternion()).angle)


def until(done, timeout: float = 120.0):
    """Wait until ``done()``, or fail the session after ``timeout`` seconds."""
    began = time.monotonic()
    while not done():
        if time.monotonic() - began > timeout:
            raise TimeoutError(f"waited {timeout:.0f} s in vain")
        yield 0.1


def solve(s, view, label: str):
    """Solve with the hotkey over the viewport and wait for its summary; record it and what touches."""
    settings = bpy.context.scene.contact_edit
    settings.last_solve = ""
    yield from s.move(*view.centre())
    yield from s.key("ctrl+shift+e", settle=0.2)
    yield from until(lambda: "evaluations in" in settings.last_solve)
    yield 0.5
    posing = addon("posing")
    problem = posing.problem(bpy.context.scene)
    met = posing.touch(problem, problem.theta0)
    s.record(label, {"summary": settings.last_solve, "gaps": met.gaps, "touching": met.touching,
                     "deepest": met.deepest})  # fmt: skip


def steps(s):
    yield from grasp(s)


def grasp(s, restyle=None):
    """The session, on the Example as it is added or as ``restyle(hand, armature)`` changes it."""
    rng = np.random.default_rng(7)
    bpy.context.preferences.view.smooth_view = 0  # views change at once (no animation to wait out)
    view = s.view3d()
    hand, mug = example(view)
    armature = hand.parent
    if restyle is not None:
        restyle(hand, armature)
    settings = bpy.context.scene.contact_edit

    # Paint: the hand alone (local view, numpad slash), seen from its palm side (numpad 3, from the right).
    for obj in bpy.context.view_layer.objects:
        obj.select_set(obj == hand)
    bpy.context.view_layer.objects.active = hand
    yield from s.move(*view.centre())
    yield from s.key("KP_Divide", settle=0.8)
    yield from s.key("KP_3", settle=0.8)
    procedural = hands.make_hand("human")  # the Example's hand: the same mesh
    for name, (bone, length, radius) in PADS.items():
        path = pad_stroke(hand, procedural, view, bone, length)
        settings.brush_radius = round(radius * pixels_per_metre(view, hand.matrix_world.translation))
        before = len(hand.contact_edit.patches)
        yield from s.move(*path[0])
        yield from s.key("ctrl+shift+p")
        yield from s.drag(path)
        yield from until(lambda count=before: len(hand.contact_edit.patches) > count)
        hand.contact_edit.patches[-1].name = name  # renamed in the list, as a person would
        yield 0.2
    s.record("painted", [(e.name, e.points) for e in hand.contact_edit.patches])
    yield from s.shot("painted")
    yield from s.key("KP_Divide", settle=0.8)

    # The person's intent: where the pads meet the mug when the fingers wrap around it; then the hand open.
    rest = {b.name: b.matrix_basis.copy() for b in armature.pose.bones}
    bpy.context.view_layer.objects.active = armature
    bpy.ops.object.mode_set(mode="POSE")
    for bone in armature.pose.bones:  # Blender 5 selects pose bones, 4 their bones
        (bone if hasattr(bone, "select") else bone.bone).select = bone.name not in {"forearm", "hand"}
    with view.override():
        bpy.ops.contact_edit.flex_to_contact(joints="IN_TURN")
    intent = addon("commands.demo")._landing(hand, armature)
    bpy.ops.object.mode_set(mode="OBJECT")
    for bone in armature.pose.bones:
        bone.matrix_basis = rest[bone.name]
    bpy.context.view_layer.update()

    # Transfer each pad by eye: the mug alone (local view), looked at where the pad goes.
    for obj in bpy.context.view_layer.objects:
        obj.select_set(obj == mug)
    bpy.context.view_layer.objects.active = mug
    yield from s.key("KP_Divide", settle=0.8)
    mug_mesh = bridge.trimesh(mug)
    intent = {name: on_surface(mug, mug_mesh, *where) for name, where in intent.items()}
    s.record("intended", sorted(intent))
    axis = np.array(mug.matrix_world.translation)
    placed = {}
    for name, (location, direction, normal) in intent.items():
        outside = normal @ ((location - axis) * [1.0, 1.0, 0.0]) > 0
        # Looked at from its side of the mug and a little above; inside the mug, from above, over the rim.
        look_at(view, location, normal + np.array([0.0, 0.0, 0.35 if outside else 1.5]), 0.25)
        yield 0.3
        tangent = np.cross(normal, rng.normal(size=3))
        off = location + MISPLACED * tangent / np.linalg.norm(tangent)
        turn = rng.uniform(-MISTURNED, MISTURNED)
        towards = direction * math.cos(turn) + np.cross(normal, direction) * math.sin(turn)
        (x, y), (x1, y1) = view.project([off, off + 0.01 * towards / np.linalg.norm(towards)])
        angle = math.atan2(y1 - y, x1 - x)
        names = [e.name for e in hand.contact_edit.patches]
        addon("store").set_active(hand, names.index(name))  # chosen in the hand's patch list
        yield from s.key("shift+alt+t", settle=0.2)
        yield from s.drag([(x + 4 * t * math.cos(angle), y + 4 * t * math.sin(angle)) for t in range(11)])
        yield 0.3
        placed[name] = [e.name for e in mug.contact_edit.patches]
    s.record("placed", placed)
    s.record("misplaced", misplacement(mug, intent))
    yield from s.shot("placed")
    s.record("paired", [(e.name, e.pair) for e in hand.contact_edit.patches])
    yield from s.key("KP_Divide", settle=0.8)

    # Solve, from the open hand as the Example left it.
    for obj in bpy.context.view_layer.objects:
        obj.select_set(obj == armature)
    bpy.context.view_layer.objects.active = armature
    look_at(view, np.array(mug.matrix_world.translation) + np.array([0.0, 0.0, 0.05]), (0.3, -1.0, 0.6), 0.4)
    start = hand_matrix(armature)
    yield from solve(s, view, "first")
    solved = hand_matrix(armature)
    s.record("first_turn", turned_by(start, solved))
    yield from s.shot("solved")

    # Turn the middle finger's patch on the mug by 45° (the rotate tool, dragged right) and solve again.
    middle = next(e.pair for e in hand.contact_edit.patches if e.name == "middle tip")
    mug_names = [e.name for e in mug.contact_edit.patches]
    bpy.context.view_layer.objects.active = mug
    addon("store").set_active(mug, mug_names.index(middle))  # chosen in the mug's patch list
    x, y = view.centre()
    yield from s.move(x, y)
    yield from s.key("shift+alt+r", settle=0.3)
    yield from s.move(x + TURN / DEGREES_PER_PIXEL, y)
    s.xdotool("click", 1)
    yield 0.5
    rotated = bpy.context.window_manager.operators[-1]
    s.record("turned", [rotated.bl_idname, math.degrees(getattr(rotated.properties, "angle", 0.0))])
    bpy.context.view_layer.objects.active = armature
    yield from solve(s, view, "second")
    s.record("second_turn", turned_by(solved, hand_matrix(armature)))
    yield from s.shot("solved_again")
