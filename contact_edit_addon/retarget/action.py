"""A retargeted motion written into the .blend: the target hand's DOF curves as one action on its armature,
the retargeting's per-frame metrics as curves in the same action (the Graph Editor plots them, with no
dependency), and its metrics plot as a packed image where matplotlib drew one.

The action keys exactly what :func:`..bridge.apply_pose` keys (the controls an animator keys, in their own
rotation modes, and the root control's location), at every given frame, but is built in one pass: every
frame's channel values are computed at once (:func:`..bridge.armature.pose_channels`) and each F-curve's
keys are filled by ``foreach_set``, not key by key. Keys take the interpolation and handle type of the
user's preferences for new keys, as ``keyframe_insert`` gives them (Blender's defaults: Bézier with
auto-clamped handles): the keys are already dense samples of a smooth motion, so the curves pass through
every sample, stay smooth between frames (subframes, motion blur, retiming) and never overshoot, and an
animator edits them as hand-made keys.

Actions are slotted from Blender 4.4 on (the F-curves live in a channelbag for the armature's slot);
before, in Blender 4.2 LTS, in the action itself.
"""

from __future__ import annotations

from pathlib import Path

import bpy
import numpy as np
from bpy_extras import anim_utils

from ..bridge.armature import PosedHand, pose_channels
from ..bridge.errors import BridgeError


def write_action(posed: PosedHand, theta, frames, name: str, replace: bool = False) -> bpy.types.Action:
    """Key a whole motion of the hand, one pose per frame, as one new action on its armature.

    Parameters
    ----------
    posed : PosedHand
        The target hand, as :func:`..bridge.posed_hand` read it.
    theta : (F, d)
        Its DOF curves, one row per frame in the order of ``posed.rig`` (not clipped to the limits).
    frames : (F,) or range
        The scene frame of each row, strictly increasing (subframes allowed).
    name : str
        The new action's name (Blender adds ``.001`` if it is taken).
    replace : bool
        Whether the new action may take the place of the armature's active action. The replaced action
        is kept: it gets a fake user if nothing else uses it, so saving does not discard it.

    Returns
    -------
    bpy.types.Action
        The new action, assigned to the armature (and to a slot for it, Blender 4.4+).

    Raises
    ------
    BridgeError
        For theta of the wrong shape or with non-finite values (naming the frames and DOFs), frames that
        are not one finite, increasing value per row, or an armature that already has an action (unless
        ``replace``) or is in NLA tweak mode; nothing is changed then.
    """
    armature = posed.armature_object()
    theta = _checked_theta(posed, theta)
    frames = _checked_frames(frames, len(theta))
    data = armature.animation_data
    if data is not None and data.use_tweak_mode:
        raise BridgeError(
            f"'{armature.name}' is in NLA tweak mode; leave it (Tab in the NLA editor) to write an action"
        )
    old = data.action if data is not None else None
    if old is not None and not replace:
        raise BridgeError(
            f"'{armature.name}' already has the action '{old.name}'; write with replace=True to put the "
            "new one in its place (the old one is kept)"
        )
    channels = pose_channels(posed, theta)
    action = bpy.data.actions.new(name)
    fcurves, slot, group_keyword = _fcurves(action, armature)
    interpolation, handle = _new_key_settings()
    n = len(frames)
    co = np.empty((n, 2), np.float32)
    co[:, 0] = frames
    for bone, path, values in channels:
        data_path = f'pose.bones["{bpy.utils.escape_identifier(bone)}"].{path}'
        for index in range(values.shape[1]):
            curve = fcurves.new(data_path, index=index, **{group_keyword: bone})
            points = curve.keyframe_points
            points.add(n)
            co[:, 1] = values[:, index]
            points.foreach_set("co", co.ravel())
            points.foreach_set("interpolation", np.full(n, interpolation, np.int32))
            points.foreach_set("handle_left_type", np.full(n, handle, np.int32))
            points.foreach_set("handle_right_type", np.full(n, handle, np.int32))
            curve.update()  # sorts the keys and computes the automatic handles
    data = armature.animation_data_create()
    if old is not None and old.users == 1 and not old.use_fake_user:
        old.use_fake_user = True  # its last user is the armature: keep it through a save
    data.action = action
    if slot is not None:
        data.action_slot = slot
    return action


#: The per-frame metrics keyed beside the pose: the armature's custom property, and what it holds.
METRICS = {
    "retarget_contacts_mm": "The frame's mean distance of the transferred contacts from the object (mm)",
    "retarget_markers_mm": "The frame's mean distance of the virtual markers from their targets (mm)",
    "retarget_hand_object_percent": "The frame's hand-object intersection (% of the hand's volume)",
    "retarget_self_intersection_percent": "The frame's self-intersection of the hand (%)",
}


def write_metrics(armature: bpy.types.Object, action: bpy.types.Action, frames, values: dict) -> None:
    """Key the retargeting's per-frame metrics (``values``: :data:`METRICS` name -> (F,) array, NaN where a
    frame has none) as linear curves of the armature's custom properties in ``action``, in a group of
    their own, so that the Graph Editor plots them beside the motion."""
    fcurves = _action_fcurves(action, armature)
    frames = np.asarray(frames, np.float64)
    for name, description in METRICS.items():
        v = np.asarray(values[name], np.float64)
        kept = np.flatnonzero(np.isfinite(v))
        armature[name] = float(v[kept[0]]) if kept.size else 0.0
        armature.id_properties_ui(name).update(description=description)
        old = fcurves.find(f'["{name}"]')
        if old is not None:
            fcurves.remove(old)
        if kept.size == 0:
            continue
        curve = fcurves.new(f'["{name}"]', **{_group_keyword(action): "Retarget metrics"})
        points = curve.keyframe_points
        points.add(kept.size)
        points.foreach_set("co", np.column_stack([frames[kept], v[kept]]).astype(np.float32).ravel())
        points.foreach_set("interpolation", np.full(kept.size, LINEAR, np.int32))
        curve.update()


def metrics_image(png_path, name: str) -> bpy.types.Image:
    """Load a PNG (the retargeting's metrics plot) into the .blend as the image ``name``, packed so that
    it travels with the file. An existing image of that name is replaced: whatever showed it shows the
    new one.

    Raises BridgeError when the file is missing or Blender cannot read it as an image.
    """
    path = Path(png_path)
    if not path.is_file():
        raise BridgeError(f"there is no metrics plot at '{path}'")
    try:
        image = bpy.data.images.load(str(path), check_existing=False)
    except RuntimeError as err:
        raise BridgeError(f"Blender cannot read '{path}' as an image: {err}") from err
    if tuple(image.size) == (0, 0):  # Blender loads an unreadable file as an empty image
        bpy.data.images.remove(image)
        raise BridgeError(f"'{path}' holds no image Blender can read")
    image.pack()
    old = bpy.data.images.get(name)
    if old is not None and old != image:
        old.user_remap(image)
        bpy.data.images.remove(old)
    image.name = name
    return image


def _checked_theta(posed: PosedHand, theta) -> np.ndarray:
    """θ as (F, d) float64, or BridgeError naming what is wrong (the shape, or the first bad frames and
    DOFs)."""
    rig = posed.rig
    theta = np.asarray(theta, np.float64)
    if theta.ndim != 2 or theta.shape[1] != rig.n_dofs or len(theta) == 0:
        raise BridgeError(
            f"theta for '{posed.armature}' needs shape (frames, {rig.n_dofs}): one row per frame, one value "
            f"per DOF of its rig; got {theta.shape}",
            posed.armature,
        )
    bad = ~np.isfinite(theta)
    if bad.any():
        rows = np.flatnonzero(bad.any(axis=1))
        dofs = np.flatnonzero(bad.any(axis=0))
        raise BridgeError(
            f"theta is not finite in {len(rows)} rows (first: {', '.join(map(str, rows[:5]))}) at DOFs "
            f"{', '.join(rig.dof_names[i] for i in dofs[:5])}",
            posed.armature,
        )
    return theta


def _checked_frames(frames, n: int) -> np.ndarray:
    """The frames as (n,) float64, or BridgeError unless they are n finite, strictly increasing values."""
    frames = np.asarray(frames, np.float64)
    if frames.ndim != 1 or len(frames) != n:
        raise BridgeError(f"there are {n} poses but {frames.size} frames; give one frame per row of theta")
    if not np.isfinite(frames).all():
        raise BridgeError(f"frame {np.flatnonzero(~np.isfinite(frames))[0]} is not a finite number")
    steps = np.flatnonzero(np.diff(frames) <= 0)
    if steps.size:
        i = steps[0]
        raise BridgeError(
            f"frames must increase: row {i + 1} is at frame {frames[i + 1]:g}, not after {frames[i]:g}"
        )
    return frames


LINEAR = bpy.types.Keyframe.bl_rna.properties["interpolation"].enum_items["LINEAR"].value


def _slotted(action: bpy.types.Action) -> bool:
    """Whether actions have slots here (Blender 4.4+), their F-curves in a channelbag per slot."""
    return hasattr(action, "slots") and hasattr(anim_utils, "action_ensure_channelbag_for_slot")


def _group_keyword(action: bpy.types.Action) -> str:
    """The keyword of ``fcurves.new`` that names an F-curve's group."""
    return "group_name" if _slotted(action) else "action_group"


def _action_fcurves(action: bpy.types.Action, armature: bpy.types.Object):
    """The F-curves of ``action`` that animate ``armature`` (its slot's, Blender 4.4+)."""
    if _slotted(action):
        return anim_utils.action_get_channelbag_for_slot(action, armature.animation_data.action_slot).fcurves
    return action.fcurves


def _fcurves(action: bpy.types.Action, armature: bpy.types.Object):
    """Where the action's F-curves go, the slot to assign with it (None before Blender 4.4) and the
    keyword naming an F-curve's group in ``fcurves.new``."""
    if _slotted(action):
        slot = action.slots.new(id_type="OBJECT", name=armature.name)
        return (
            anim_utils.action_ensure_channelbag_for_slot(action, slot).fcurves,
            slot,
            _group_keyword(action),
        )
    action.id_root = "OBJECT"
    return action.fcurves, None, _group_keyword(action)


def _new_key_settings() -> tuple[int, int]:
    """The enum values of the interpolation and handle type the user's preferences give new keys."""
    edit = bpy.context.preferences.edit
    keyframe = bpy.types.Keyframe.bl_rna.properties
    return (
        keyframe["interpolation"].enum_items[edit.keyframe_new_interpolation_type].value,
        keyframe["handle_left_type"].enum_items[edit.keyframe_new_handle_type].value,
    )
