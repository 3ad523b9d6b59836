"""Copy contacts and poses from one side to the other, the way Blender's X mirror works: patches go to the
mirror-image points of the other hand (or the other half of a symmetric body), named by Blender's
.L/.R rule; a pose goes to the bones with the flipped names, as Pose › Paste Pose Flipped does."""

from __future__ import annotations

import bpy
import numpy as np

from geodesics import ContactSet, MirrorMap, TriMesh, flip_name, mirror_contacts
from solver.rig import PoseChannel, mirror_pose

from .. import bridge, store
from .common import KEYFRAME, ExplainedPoll, guarded, key_frame, keyed, mesh_object, need_patch


def mirror_space(obj: bpy.types.Object) -> np.ndarray:
    """(4, 4) the space whose x = 0 plane is the mirror for ``obj``: its armature's, else the world."""
    for modifier in obj.modifiers:
        if modifier.type == "ARMATURE" and modifier.object is not None:
            return np.array(modifier.object.matrix_world)
    return np.eye(4)


def in_space(mesh: TriMesh, obj: bpy.types.Object, space: np.ndarray) -> TriMesh:
    """The object's mesh with its vertices carried into ``space`` (same faces, so the same surface points)."""
    return bridge.moved(mesh, np.linalg.inv(space) @ np.array(obj.matrix_world))


def counterpart(obj: bpy.types.Object) -> bpy.types.Object:
    """The object named for the other side (``Hand.L`` → ``Hand.R``), else the object itself."""
    other = bpy.data.objects.get(flip_name(obj.name))
    return other if other is not None and other.type == "MESH" else obj


def mirror_patches(source: bpy.types.Object, target: bpy.types.Object, names, overwrite: bool) -> list[str]:
    """Mirror the named patches of ``source`` onto ``target`` (which may be ``source``, symmetric in itself),
    in the layer ``source`` edits (its contacts, or its annotation, markers staying markers); returns the
    new patches' names."""
    space = mirror_space(source)
    layer = source.contact_edit.layer
    contacts = store.load(source, layer=layer)
    if not len(contacts):
        raise bridge.BridgeError(f"'{source.name}' has no contact patches to mirror", source.name)
    ours = in_space(contacts.mesh, source, space)
    mine = ContactSet.from_dict(contacts.to_dict(), ours)
    if target == source:
        mirror, into = MirrorMap(ours), mine
    else:
        existing = store.load(target, layer=layer)
        theirs = in_space(existing.mesh, target, space)
        mirror, into = MirrorMap(ours, theirs), ContactSet.from_dict(existing.to_dict(), theirs)
    mirrored = mirror_contacts(mine, mirror, names=names, into=into, overwrite=overwrite)
    real = store.load(target, layer=layer).mesh
    markers = {flip_name(e.name) for e in store.entries(source, layer) if e.marker and e.name in names}
    store.save(target, ContactSet.from_dict(mirrored.to_dict(), real), layer=layer, markers=markers)
    return [flip_name(n) for n in names]


class CONTACT_EDIT_OT_mirror_contacts(ExplainedPoll, bpy.types.Operator):
    """Copy contact patches to the other side: onto the object named for it (Hand.L → Hand.R), or onto the
    other half of the same mesh"""

    bl_idname = "contact_edit.mirror_contacts"
    bl_label = "Mirror Contacts"
    bl_options = {"REGISTER", "UNDO"}

    scope: bpy.props.EnumProperty(
        name="Patches",
        items=[("ACTIVE", "Active", "The active patch"), ("ALL", "All", "Every patch of the object")],
        default="ACTIVE",
    )
    object_name: bpy.props.StringProperty(name="Object", description="Default: the active object")
    target_name: bpy.props.StringProperty(
        name="Onto", description="Default: the object named for the other side, else the same object"
    )
    overwrite: bpy.props.BoolProperty(name="Replace", description="Replace patches that have the new names")

    why_not = staticmethod(need_patch)

    @guarded
    def execute(self, context):
        source = mesh_object(context, self.object_name or None)
        target = mesh_object(context, self.target_name) if self.target_name else counterpart(source)
        names = list(store.load(source)) if self.scope == "ALL" else [store.active_patch_name(source)]
        made = mirror_patches(source, target, names, self.overwrite)
        self.report({"INFO"}, f"Mirrored {', '.join(made)} onto '{target.name}'")
        store.redraw()
        return {"FINISHED"}


class CONTACT_EDIT_OT_mirror_pose(ExplainedPoll, bpy.types.Operator):
    """Give the other side the mirror image of this side's pose, as Paste Pose Flipped does: the hand's
    solved controls, or the selected bones"""

    bl_idname = "contact_edit.mirror_pose"
    bl_label = "Mirror Pose"
    bl_options = {"REGISTER", "UNDO"}

    bones: bpy.props.EnumProperty(
        name="Bones",
        items=[
            ("HAND", "Hand controls", "The controls a solve of the hand poses"),
            ("SELECTED", "Selected", "The bones selected in Pose Mode"),
        ],
        default="HAND",
    )
    keyframe: bpy.props.BoolProperty(**KEYFRAME)

    @staticmethod
    def why_not(context) -> str | None:
        if context.scene.contact_edit.hand is None:
            return "Choose the hand in the Contact tab first"
        return None

    @guarded
    def execute(self, context):
        hand = context.scene.contact_edit.hand
        armature = bridge.armature_modifier(hand).object
        if self.bones == "HAND":
            rig = bridge.hand_rig(hand)
            plan = bridge.hand_plan(
                rig, bridge.trimesh(hand).faces, hand_root=context.scene.contact_edit.hand_root
            )
            chosen = [n for n in (plan.root, *plan.controls) if n]
        else:
            chosen = sorted(bridge.selected_bones(armature))
        if not chosen:
            raise bridge.BridgeError(f"no bone of '{armature.name}' to mirror: select some in Pose Mode")
        pose = {b.name: PoseChannel.from_object(b) for b in armature.pose.bones}
        after = mirror_pose(pose, selected=chosen)
        changed = [n for n in dict.fromkeys(flip_name(c) for c in chosen) if n in after]
        frame = key_frame(self, context)
        for name in changed:
            pose_bone = armature.pose.bones[name]
            after[name].apply_to(pose_bone)
            if frame is not None:
                for path in ("location", bridge.rotation_path(pose_bone.rotation_mode), "scale"):
                    pose_bone.keyframe_insert(path, frame=frame, group=name)
        self.report(
            {"INFO"},
            f"Mirrored {len(chosen)} bones onto {len(changed)}: {', '.join(changed[:4])}"
            + (", …" if len(changed) > 4 else "")
            + keyed(frame, "them"),
        )
        return {"FINISHED"}


classes = (CONTACT_EDIT_OT_mirror_contacts, CONTACT_EDIT_OT_mirror_pose)
