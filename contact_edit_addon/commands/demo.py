"""The embedded default job: a procedural human hand grasps a mug, the way an animator would do it.

Every step runs the add-on's own operators, as clicks would: paint a contact pad on each fingertip and
on the palm with the area brush (one dab each); wrap the fingers around the mug (flex to contact, joint
by joint from the knuckles) to see where the pads land; transfer each pad onto the mug there; open the
hand again and key it; solve the pose from the contacts alone and key it 23 frames later. The scene is
saved with its contacts, the contact pairing is written as a file for ``contact-edit pose``, and a
small Cycles render (denoised, on a floor with soft shadows) shows the grasp. What the solve reaches is
measured, not assumed: which pads touch the mug and how deep the hand is inside it (its deepest vertex,
and the deepest point of its faces, which can cut the mug's rim between vertices).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import bpy
import numpy as np
from mathutils import Vector
from scipy.spatial import cKDTree

from solver import palm_centre

from .. import assets, bridge, posing, store

#: Contact pads brushed on the hand: name -> (the bone whose palm-side skin the pad is on, the radius of
#: the brush's dab in metres). Small enough that a round fingertip can rest on the mug along all of it.
PADS = {
    "palm": ("hand", 0.012),
    "thumb tip": ("thumb_3", 0.005),
    "index tip": ("index_3", 0.005),
    "middle tip": ("middle_3", 0.005),
    "ring tip": ("ring_3", 0.005),
    "pinky tip": ("pinky_3", 0.005),
}
#: The brush's density, contact points per cm² (the add-on's default).
DENSITY = 100.0
#: A pad is transferred where it lands if the wrapped hand brings it this close to the mug (metres).
LANDING_DISTANCE = 0.01
OPEN_FRAME, GRASP_FRAME = 1, 24


@dataclass(frozen=True)
class DemoResult:
    """What the demo made and measured (lengths in metres)."""

    blend: Path
    image: Path | None
    contacts_file: Path
    painted: tuple[str, ...]
    transferred: tuple[str, ...]
    touching: tuple[str, ...]
    deepest: float
    deepest_face: float
    contacts: int
    summary: str
    seconds: float


#: The files :func:`run` writes into its folder (the image only when it renders).
FILES = {"contacts": "contacts.json", "image": "demo.png", "blend": "demo.blend"}


def run(out: Path, render: bool = True, progress: Callable[[str], None] = lambda _: None) -> DemoResult:
    """Build, pose, save and render the demo scene into the folder ``out`` (created if needed)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    progress("building the hand and the mug")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    hand, hand_obj, mug = assets.example_scene(bpy.context, np.zeros(3))
    armature = hand_obj.parent

    progress("painting contact pads on the hand")
    bpy.context.view_layer.objects.active = hand_obj
    scene.contact_edit.brush_density = DENSITY
    for name, (bone, radius) in PADS.items():
        face = _pad_centre(hand, bone)
        corners = bridge.mesh_arrays(hand_obj.data)[0][hand.mesh.faces[face]]
        centre = bridge.object_to_world(hand_obj, corners.mean(0)[None])[0]
        dab = {"name": "", "location": centre, "polygon": int(face), "radius": radius}
        bpy.ops.contact_edit.paint(name=name, source="STROKE", object_name=hand_obj.name, stroke=[dab])

    progress("wrapping the fingers around the mug")
    for bone in armature.pose.bones:
        bone.select = bone.name not in {"forearm", "hand"}
    bpy.ops.contact_edit.flex_to_contact(joints="IN_TURN")
    landed = _landing(hand_obj, armature)

    progress(f"transferring {len(landed)} pads onto the mug")
    for name, (location, direction) in landed.items():
        bpy.ops.contact_edit.transfer(patch=name, location=location, direction=direction, hierarchy=False)

    progress("solving the grasp from the open hand")
    posed = bridge.posed_hand(hand_obj, store.load(hand_obj, layer="CONTACTS").mesh.faces)
    scene.frame_set(OPEN_FRAME)
    bridge.apply_pose(posed, posed.rig.rest, OPEN_FRAME)
    scene.frame_set(GRASP_FRAME)
    bpy.ops.contact_edit.solve(stage="ALL", keyframe=True)
    scene.frame_start, scene.frame_end = OPEN_FRAME, GRASP_FRAME
    problem = posing.problem(scene)  # the solved pose as the scene holds it now, measured
    met = posing.touch(problem, problem.theta0, faces=True)

    contacts_file = out / FILES["contacts"]
    store.save_pairing(contacts_file, hand_obj, mug)
    image = None
    if render:
        progress("rendering (Cycles, CPU, denoised)")
        image = out / FILES["image"]
        _render(scene, [hand_obj, mug], image)
    blend = out / FILES["blend"]
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), check_existing=False)
    hand_set = store.load(hand_obj, layer="CONTACTS")
    return DemoResult(
        blend=blend,
        image=image,
        contacts_file=contacts_file,
        painted=tuple(PADS),
        transferred=tuple(landed),
        touching=met.touching,
        deepest=float(met.deepest or 0.0),
        deepest_face=float(met.deepest_face or 0.0),
        contacts=sum(len(hand_set[name]) for name in landed),
        summary=scene.contact_edit.last_solve,
        seconds=time.perf_counter() - start,
    )


def _pad_centre(hand, bone: str) -> int:
    """The palm-side face at the middle of a bone's pad: nearest the area-weighted centre of the bone's
    palm-side skin (of the palm's, for the palm)."""
    mesh = hand.mesh
    faces = hand.palmar_faces(hand.rig.bone_index(bone))
    centroids = mesh.vertices[mesh.faces[faces]].mean(1)
    area = mesh.face_areas[faces]
    centre = (centroids * area[:, None]).sum(0) / area.sum() if bone != "hand" else palm_centre(hand)
    return int(faces[np.argmin(np.linalg.norm(centroids - centre, axis=1))])


def _landing(hand_obj, armature) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """For each hand pad the wrapped hand brings near the mug: where its axis starts (world) and the
    world direction it leaves in."""
    contacts = store.load(hand_obj, layer="CONTACTS")
    posed = bridge.posed_hand(hand_obj, contacts.mesh.faces)
    theta = posed.start
    mug = bpy.context.scene.contact_edit.target
    mug_mesh = bridge.trimesh(mug)
    tree = cKDTree(bridge.object_to_world(mug, mug_mesh.vertices))
    A = np.array(armature.matrix_world)
    landed = {}
    for name in contacts:
        axis = contacts[name].axis.points
        positions, _ = posed.skin.posed_points(theta, axis[[0, 1]])
        world = positions @ A[:3, :3].T + A[:3, 3]
        patch_points, _ = posed.skin.posed_points(theta, contacts[name].points)
        gap, _ = tree.query(patch_points @ A[:3, :3].T + A[:3, 3])
        if gap.min() < LANDING_DISTANCE:
            landed[name] = (world[0], world[1] - world[0])
    return landed


#: The render: Cycles samples per pixel (denoised, so few are needed) and the sun's angular diameter,
#: which softens the shadows' edges.
SAMPLES, SUN_ANGLE = 32, math.radians(6.0)


def _render(scene, shown, path: Path) -> None:
    """A small Cycles CPU render framing the shown objects on a floor, denoised by OpenImageDenoise."""
    colours = {"Hand": (0.80, 0.57, 0.45, 1.0), "Mug": (0.20, 0.42, 0.75, 1.0)}
    for obj in shown:
        material = bpy.data.materials.new(obj.name)
        material.use_nodes = True
        material.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = colours[obj.name]
        obj.data.materials.append(material)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    corners = []
    for obj in shown:
        evaluated = obj.evaluated_get(depsgraph)
        corners += [evaluated.matrix_world @ Vector(c) for c in evaluated.bound_box]
    lo, hi = np.min(corners, axis=0), np.max(corners, axis=0)
    centre, radius = Vector((lo + hi) / 2), float(np.linalg.norm(hi - lo) / 2)
    _floor(scene, centre, height=float(lo[2]), size=20 * radius)
    camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(camera)
    view = Vector((0.35, -1.0, 0.45)).normalized()
    distance = radius / math.tan(camera.data.angle / 2) * 1.05
    camera.location = centre + view * distance
    camera.rotation_euler = (-view).to_track_quat("-Z", "Y").to_euler()
    scene.camera = camera
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.data.energy = 3.0
    sun.data.angle = SUN_ANGLE
    sun.rotation_euler = (math.radians(40), math.radians(-20), math.radians(-30))
    scene.collection.objects.link(sun)
    world = bpy.data.worlds.new("World")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.8, 0.8, 0.82, 1.0)
    scene.world = world
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = SAMPLES
    scene.cycles.use_denoising = True
    scene.cycles.denoiser = "OPENIMAGEDENOISE"
    scene.render.resolution_x, scene.render.resolution_y = 480, 360
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)


def _floor(scene, centre: Vector, height: float, size: float) -> None:
    """A grey square floor under everything shown (its top at ``height``), to catch the shadows."""
    h = size / 2
    corners = [(centre.x + x, centre.y + y, height) for x, y in ((-h, -h), (h, -h), (h, h), (-h, h))]
    data = bpy.data.meshes.new("Floor")
    data.from_pydata(corners, [], [(0, 1, 2, 3)])
    material = bpy.data.materials.new("Floor")
    material.use_nodes = True
    material.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.62, 0.62, 0.64, 1.0)
    data.materials.append(material)
    scene.collection.objects.link(bpy.data.objects.new("Floor", data))
