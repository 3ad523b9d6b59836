"""Bone constraints as data: the settings of one constraint by Blender's RNA names, its targets, Blender's
defaults, and what is modelled exactly (:meth:`Constraint.unsupported` names what is not)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...rotations import EULER_ORDERS
from ..bones import Bone
from ..spaces import SPACES

#: Blender's defaults of the settings each modelled constraint type reads (RNA property names).
DEFAULTS: dict[str, dict[str, Any]] = {
    "COPY_LOCATION": dict(
        use_x=True, use_y=True, use_z=True, invert_x=False, invert_y=False, invert_z=False, use_offset=False
    ),
    "COPY_ROTATION": dict(
        use_x=True,
        use_y=True,
        use_z=True,
        invert_x=False,
        invert_y=False,
        invert_z=False,
        mix_mode="REPLACE",
        euler_order="AUTO",
    ),
    "COPY_SCALE": dict(
        use_x=True, use_y=True, use_z=True, power=1.0, use_make_uniform=False, use_offset=False, use_add=False
    ),
    "COPY_TRANSFORMS": dict(mix_mode="REPLACE", remove_target_shear=False),
    "STRETCH_TO": dict(
        rest_length=0.0,
        bulge=1.0,
        use_bulge_min=False,
        use_bulge_max=False,
        bulge_min=1.0,
        bulge_max=1.0,
        bulge_smooth=0.0,
        volume="VOLUME_XZX",
        keep_axis="PLANE_X",
    ),
    "CHILD_OF": dict(
        use_location_x=True,
        use_location_y=True,
        use_location_z=True,
        use_rotation_x=True,
        use_rotation_y=True,
        use_rotation_z=True,
        use_scale_x=True,
        use_scale_y=True,
        use_scale_z=True,
        inverse_matrix=np.eye(4),
        set_inverse_pending=False,
    ),
    "ARMATURE": dict(use_deform_preserve_volume=False, use_bone_envelopes=False, use_current_location=False),
    "LIMIT_ROTATION": dict(
        use_limit_x=False,
        use_limit_y=False,
        use_limit_z=False,
        min_x=0.0,
        max_x=0.0,
        min_y=0.0,
        max_y=0.0,
        min_z=0.0,
        max_z=0.0,
        euler_order="AUTO",
        use_legacy_behavior=False,
    ),
    "LIMIT_LOCATION": dict(
        use_min_x=False,
        use_max_x=False,
        use_min_y=False,
        use_max_y=False,
        use_min_z=False,
        use_max_z=False,
        min_x=0.0,
        max_x=0.0,
        min_y=0.0,
        max_y=0.0,
        min_z=0.0,
        max_z=0.0,
    ),
    "LIMIT_SCALE": dict(
        use_min_x=False,
        use_max_x=False,
        use_min_y=False,
        use_max_y=False,
        use_min_z=False,
        use_max_z=False,
        min_x=0.0,
        max_x=0.0,
        min_y=0.0,
        max_y=0.0,
        min_z=0.0,
        max_z=0.0,
    ),
    "DAMPED_TRACK": dict(track_axis="TRACK_Y"),
    "TRACK_TO": dict(track_axis="TRACK_NEGATIVE_Z", up_axis="UP_Y", use_target_z=False),
    "LOCKED_TRACK": dict(track_axis="TRACK_Y", lock_axis="LOCK_Z"),
}
#: Constraint types modelled exactly.
MODELLED = tuple(DEFAULTS)
#: Types without targets.
TARGETLESS = ("LIMIT_ROTATION", "LIMIT_LOCATION", "LIMIT_SCALE")
#: Blender's track axes, in the order of its ``TRACK_X ... TRACK_nZ`` codes.
TRACK_AXES = ("TRACK_X", "TRACK_Y", "TRACK_Z", "TRACK_NEGATIVE_X", "TRACK_NEGATIVE_Y", "TRACK_NEGATIVE_Z")
_MIX_ROTATION = ("REPLACE", "ADD", "BEFORE", "AFTER", "OFFSET")
_MIX_TRANSFORMS = ("REPLACE", "BEFORE_FULL", "AFTER_FULL", "BEFORE", "AFTER", "BEFORE_SPLIT", "AFTER_SPLIT")


@dataclass(frozen=True, eq=False)
class Target:
    """One target of a constraint.

    Attributes
    ----------
    subtarget : str
        A bone of the owner's armature ("" for an object target, given by ``matrix``).
    matrix : (4, 4) ndarray or None
        The world matrix of an object target (a constant).
    head_tail : float
        Where along the target bone (0 head, 1 tail) the target is taken (the constraint's ``head_tail``).
    use_bbone_shape : bool
        The constraint's ``use_bbone_shape`` (follow a B-Bone's curve).
    weight : float
        Armature constraint weight.
    bbone_segments : int
        Segments of the target bone (B-Bone targets need the curve).
    euler_order : str
        The Euler order of an object target's rotation mode (bone targets use their Bone's).
    """

    subtarget: str = ""
    matrix: np.ndarray | None = None
    head_tail: float = 0.0
    use_bbone_shape: bool = False
    weight: float = 1.0
    bbone_segments: int = 1
    euler_order: str = "XYZ"

    def __post_init__(self):
        if self.matrix is not None:
            m = np.array(self.matrix, dtype=np.float64).reshape(4, 4)
            m.setflags(write=False)
            object.__setattr__(self, "matrix", m)


@dataclass(frozen=True, eq=False)
class Constraint:
    """One enabled bone constraint.

    Attributes
    ----------
    type : str
        Blender's constraint type (``COPY_TRANSFORMS`` ...).
    name : str
    influence : float
    owner_space, target_space : str
        One of :data:`solver.rig.spaces.SPACES`.
    targets : tuple of Target
    settings : Mapping
        The type's settings by RNA property name; missing ones take Blender's defaults (:data:`DEFAULTS`).
    space_subtarget : str
        The bone whose pose is the ``CUSTOM`` space ("" when it is an object, ``space_matrix``).
    space_matrix : (4, 4) ndarray or None
        The world matrix of the ``CUSTOM`` space's object (identity when none).
    refusal : str or None
        Why a reader found this constraint not modellable (e.g. a target in another armature).
    """

    type: str
    name: str = ""
    influence: float = 1.0
    owner_space: str = "WORLD"
    target_space: str = "WORLD"
    targets: tuple[Target, ...] = ()
    settings: Mapping[str, Any] = field(default_factory=dict)
    space_subtarget: str = ""
    space_matrix: np.ndarray | None = None
    refusal: str | None = None

    def __post_init__(self):
        object.__setattr__(self, "targets", tuple(self.targets))
        object.__setattr__(self, "settings", dict(self.settings))

    def get(self, key: str):
        """A setting, or Blender's default for it."""
        if key in self.settings:
            return self.settings[key]
        return DEFAULTS[self.type][key]

    def unsupported(self) -> str | None:
        """Why this constraint or one of its options is not modelled exactly, in words; None if it is."""
        what = f"{self.type.replace('_', ' ').title()} constraint {self.name!r}"
        if self.refusal:
            return f"{what}: {self.refusal}"
        if self.type not in MODELLED:
            return f"{what}: constraints of type {self.type} are not modelled"
        for space in (self.owner_space, self.target_space):
            if space not in SPACES:
                return f"{what}: the {space} space is not modelled"
        if self.type not in TARGETLESS and not self.targets:
            return f"{what}: it has no target"
        for target in self.targets:
            if not target.subtarget and target.matrix is None:
                return f"{what}: a target has neither a bone nor a matrix"
            if self.type == "ARMATURE":
                if not target.subtarget:
                    return f"{what}: Armature constraint targets must be bones of the same armature"
                if target.bbone_segments > 1:
                    return f"{what}: target {target.subtarget!r} is a B-Bone (its segments deform)"
                continue
            if not target.subtarget and self.target_space not in ("WORLD", "CUSTOM"):
                return f"{what}: object targets are modelled in World and Custom space only"
            bbone = target.use_bbone_shape and target.bbone_segments > 1
            if bbone and (target.head_tail >= 1e-6 or self.type == "COPY_TRANSFORMS"):
                return f"{what}: following the B-Bone shape of {target.subtarget!r} is not modelled yet"
        if self.type == "COPY_ROTATION" and self.get("mix_mode") not in _MIX_ROTATION:
            return f"{what}: mix mode {self.get('mix_mode')} is not modelled"
        if self.type == "COPY_TRANSFORMS" and self.get("mix_mode") not in _MIX_TRANSFORMS:
            return f"{what}: mix mode {self.get('mix_mode')} is not modelled"
        if self.type == "STRETCH_TO" and self.get("rest_length") == 0:
            return f"{what}: its rest length is not computed yet (Blender sets it on first evaluation)"
        if self.type == "CHILD_OF" and self.get("set_inverse_pending"):
            return f"{what}: a Set Inverse is pending"
        for key in ("euler_order",):
            if key in DEFAULTS.get(self.type, {}) and self.get(key) not in ("AUTO", *EULER_ORDERS):
                return f"{what}: Euler order {self.get(key)} is not modelled"
        return None


@dataclass(frozen=True, eq=False)
class TargetBone:
    """What a constraint needs of a bone it targets: its rest data, its parent's, and their poses
    (``pose`` and ``parent_pose`` (..., 4, 4); ``parent_pose`` None when not needed)."""

    bone: Bone
    parent: Bone | None
    pose: np.ndarray
    parent_pose: np.ndarray | None = None
