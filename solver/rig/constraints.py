"""Blender's bone constraints, exactly: ``BKE_pose_where_is_bone`` in numpy, for one bone or a stack.

:func:`pose_bone` ports ``BKE_pose_where_is_bone`` (armature.cc): the local channel matrix through the
parent (:func:`solver.rig.bones.bone_to_pose`), then ``BKE_constraints_solve`` (constraint.cc): for each
constraint the owner's world matrix is converted into the owner space, the targets' matrices
(``constraint_target_to_mat4``, with ``head_tail``) into the target space, the type's ``*_evaluate`` runs,
the result goes back to world space (not after Child Of: ``CONSTRAINT_SPACEONCE``) and is blended with
the matrix before the constraint by :func:`solver.rig.bones.interpolate` when the influence is below 1.
Connected bones keep their head ("prevent constraints breaking a chain").

:func:`stack_pose_bones` does the same for ``g`` bones at once: bones whose discrete settings agree
(:func:`solver.rig.bones.bone_key`, and :func:`constraint_key` for each constraint of their stacks) are
posed by one :class:`solver.rig.bones.BoneStack` and one :class:`ConstraintStack` per constraint, the
continuous settings (influence, ``head_tail``, rest lengths, inverse matrices, limits ...) being arrays
over the stack. It works in pose space and skips what cannot change the result: constraints in world
space whose type reads the same in pose space under the armature's world matrix (Copy Transforms with
Replace, Copy Location and Copy Scale with default options, Stretch To, Damped Track ...), the parent and
channels of a bone whose transform a constraint replaces, and world matrices that are the identity.
:func:`pose_bone` is the stack of one bone.

Settings use Blender's RNA property names (``mix_mode``, ``use_offset``, ``head_tail`` ...); what is not
modelled exactly is named by :meth:`Constraint.unsupported`, and :func:`pose_bone` refuses it.

Everything is batched over leading dimensions and analytic for complex-step differentiation (see
:mod:`solver.rig.analytic` and :mod:`solver.rig.bones`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import SolverError
from ..rotations import EULER_ORDERS, euler_to_matrix, order_axes
from . import analytic
from .bones import (
    _AFTER,
    _NEXT,
    _ONES3,
    FLT_EPSILON,
    SPACES,
    Bone,
    BoneStack,
    Parenting,
    SharedValues,
    Spaces,
    World,
    axis_angle_matrix,
    bone_key,
    cbrt_abs,
    column_norms_squared,
    compose,
    cross,
    decompose,
    det3,
    dot,
    from_stack,
    interpolate,
    inverse3,
    inverse_affine,
    matmul,
    matrix_to_quaternion,
    matrix_to_size,
    normalize,
    normalize_axes,
    orthogonalize_stable,
    owner_orientation,
    quaternion_to_matrix,
    rescale,
    skew,
    to_stack,
    transform_point,
    with_translation,
)
from .bones import (
    shared as _shared,
)

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
_TRACK_DIRECTIONS = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [-1, 0, 0], [0, -1, 0], [0, 0, -1]], float)
_MIX_ROTATION = ("REPLACE", "ADD", "BEFORE", "AFTER", "OFFSET")
_MIX_TRANSFORMS = ("REPLACE", "BEFORE_FULL", "AFTER_FULL", "BEFORE", "AFTER", "BEFORE_SPLIT", "AFTER_SPLIT")
#: ``EULER_HYPOT_EPSILON`` of math_rotation.cc: below it the third Euler angle is taken as 0.
EULER_HYPOT_EPSILON = 0.0000375


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
        One of :data:`solver.rig.bones.SPACES`.
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


# ----------------------------------------------------------------------------------------------------
# Euler angles as Blender's constraints take them (math_rotation.cc).


def _atan2(y, x):
    """:func:`analytic.atan2` of arrays of one dtype."""
    if y.dtype != np.complex128:
        return np.arctan2(y, x)
    yr, xr = y.real, x.real
    r2 = xr * xr + yr * yr
    if r2.min() > 0:
        return np.arctan2(yr, xr) + 1j * ((xr * y.imag - yr * x.imag) / r2)
    return analytic.atan2(y, x)


# Per Euler order: flat indices (3 b + a of Blender's mat[a][b], numpy M[..., b, a]) of the numerators
# B(j,k), B(i,k), B(i,j) and of the denominators B(k,k), B(i,i); where each slot's angle goes.
_EULER_TABLES = {}
for _order in EULER_ORDERS:
    _i, _j, _k = order_axes(_order)
    _slots = np.empty(3, dtype=int)
    _slots[[_i, _j, _k]] = [0, 1, 2]
    _EULER_TABLES[_order] = (
        np.array([3 * _k + _j, 3 * _k + _i, 3 * _j + _i]),
        np.array([3 * _k + _k, 3 * _i + _i]),
        np.concatenate([_slots, _slots + 3]),
        -1.0 if _order in ("XZY", "YXZ", "ZYX") else 1.0,
    )
_EULER_SIGNS = np.array([1.0, -1.0, 1.0, -1.0, -1.0, -1.0])


def _eulo2(M, order: str):
    """``mat3_normalized_to_eulo2``: the two Euler solutions (..., 3) of a normalized (..., 3, 3)."""
    numerators, denominators, slots, parity = _EULER_TABLES[order]
    i, j, _ = order_axes(order)
    flat = M.reshape(*M.shape[:-2], 9)
    cy = np.sqrt(flat[..., 3 * i + i] ** 2 + flat[..., 3 * j + i] ** 2)
    if not (cy.size and cy.real.min() > EULER_HYPOT_EPSILON):
        return _eulo2_general(M, order)
    y = flat[..., numerators]
    xd = flat[..., denominators]
    x = np.empty((*y.shape[:-1], 6), dtype=y.dtype)
    x[..., 0], x[..., 1], x[..., 2] = xd[..., 0], cy, xd[..., 1]
    x[..., 3:] = -x[..., :3]
    angles = _atan2(np.concatenate([y, y], -1) * _EULER_SIGNS, x)[..., slots]
    if parity < 0:
        angles = -angles
    return angles[..., :3], angles[..., 3:]


def _eulo2_general(M, order: str):
    i, j, k = order_axes(order)
    parity = order in ("XZY", "YXZ", "ZYX")

    def B(a, b):  # Blender's mat[a][b]
        return M[..., b, a]

    cy = analytic.norm(np.stack([B(i, i), B(i, j)], -1))
    ok = cy.real > EULER_HYPOT_EPSILON
    shape = (*M.shape[:-2], 3)
    e1 = np.zeros(shape, dtype=M.dtype)
    e2 = np.zeros(shape, dtype=M.dtype)
    e1[..., i] = np.where(ok, analytic.atan2(B(j, k), B(k, k)), analytic.atan2(-B(k, j), B(j, j)))
    e1[..., j] = analytic.atan2(-B(i, k), cy)
    e1[..., k] = np.where(ok, analytic.atan2(B(i, j), B(i, i)), 0.0)
    e2[..., i] = analytic.atan2(-B(j, k), -B(k, k))
    e2[..., j] = analytic.atan2(-B(i, k), -cy)
    e2[..., k] = analytic.atan2(-B(i, j), -B(i, i))
    e2 = np.where(ok[..., None], e2, e1)
    if parity:
        e1, e2 = -e1, -e2
    return e1, e2


def _unit3(M):
    """The 3×3 parts of (..., 4, 4) or (..., 3, 3) ``M`` with unit columns (zero columns stay zero)."""
    A = np.asarray(M)[..., :3, :3]
    d = column_norms_squared(A)
    if d.size and d.real.min() > 1e-35:
        return A / np.sqrt(d)[..., None, :]
    units, _ = normalize(A.swapaxes(-1, -2))
    return units.swapaxes(-1, -2)


def matrix_to_euler(M, order: str):
    """(..., 3) ``mat4_to_eulO`` of ``M`` (..., 4, 4) or (..., 3, 3): axes normalized, the solution with
    the smaller ``Σ|angle|``."""
    return normalized_matrix_to_euler(_unit3(M), order)


def normalized_matrix_to_euler(M, order: str):
    """(..., 3) ``mat3_normalized_to_eulO`` of (..., 3, 3) taken as they are (``quat_to_eulO`` of a quaternion
    that is not of unit length gives what Blender gives): the solution with the smaller ``Σ|angle|``."""
    e1, e2 = _eulo2(np.asarray(M)[..., :3, :3], order)
    d1 = np.abs(e1.real) @ _ONES3
    d2 = np.abs(e2.real) @ _ONES3
    return np.where((d1 > d2)[..., None], e2, e1)


def compatible_euler(eul, old):
    """(..., 3) ``compatible_eul``: ``eul`` (..., 3) shifted by turns to be closest to ``old`` (..., 3) (the
    two broadcast)."""
    old = np.asarray(old)
    eul = np.asarray(eul)
    if eul.shape != old.shape:
        eul = np.broadcast_to(eul, np.broadcast_shapes(eul.shape, old.shape))
    two_pi = 2.0 * np.pi
    d = (eul - old).real
    up, down = d > np.pi, d < -np.pi
    if up.any() or down.any():
        shift = np.where(up, -np.floor(d / two_pi + 0.5), np.where(down, np.floor(-d / two_pi + 0.5), 0.0))
        eul = eul + shift * two_pi
        d = (eul - old).real
    a = np.abs(d)
    big = a > np.pi
    if big.any():
        small = a < np.pi / 2
        flip = big & small[..., _NEXT] & small[..., _AFTER]
        eul = eul + np.where(flip, np.where(d > 0, -two_pi, two_pi), 0.0)
    return eul if eul.flags.writeable else eul.copy()


def matrix_to_compatible_euler(M, old, order: str):
    """(..., 3) ``mat4_to_compatible_eulO`` of ``M`` (..., 4, 4) or (..., 3, 3): the solution closest to
    ``old`` (..., 3)."""
    e1, e2 = _eulo2(_unit3(M), order)
    e1, e2 = compatible_euler(e1, old), compatible_euler(e2, old)
    old = np.asarray(old).real
    d1 = np.abs(e1.real - old) @ _ONES3
    d2 = np.abs(e2.real - old) @ _ONES3
    return np.where((d1 > d2)[..., None], e2, e1)


def _axis_rotation(axis: int, cos, sin):
    """(..., 3, 3) the rotation about a coordinate axis by the angle of ``(cos, sin)`` (...)."""
    return _AXIS_ONE[axis] + cos[..., None, None] * _AXIS_COS[axis] + sin[..., None, None] * _AXIS_SIN[axis]


def _loc_euler_size(loc, eul, size, order):
    return compose(loc, euler_to_matrix(eul, order), size)


# ----------------------------------------------------------------------------------------------------
# Stacks: the settings of many constraints of one kind, as arrays.

#: The settings of each type that are continuous: arrays over a :class:`ConstraintStack`. The others
#: are discrete, part of :func:`constraint_key`.
CONTINUOUS: dict[str, tuple[str, ...]] = {
    "COPY_SCALE": ("power",),
    "STRETCH_TO": ("rest_length", "bulge", "bulge_min", "bulge_max", "bulge_smooth"),
    "CHILD_OF": ("inverse_matrix",),
    "LIMIT_ROTATION": ("min_x", "max_x", "min_y", "max_y", "min_z", "max_z"),
    "LIMIT_LOCATION": ("min_x", "max_x", "min_y", "max_y", "min_z", "max_z"),
    "LIMIT_SCALE": ("min_x", "max_x", "min_y", "max_y", "min_z", "max_z"),
}
_LOCAL_SPACES = ("LOCAL", "LOCAL_OWNER_ORIENT")
_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0])
_EYE4 = np.eye(4)
_EYE4.setflags(write=False)


def _bone_of(bones: Mapping[str, Any], name: str, what: str) -> Bone:
    try:
        b = bones[name]
    except KeyError:
        raise SolverError(f"{what} reads bone {name!r}, which was not given") from None
    return b.bone if isinstance(b, TargetBone) else b


def _hashable(value):
    if isinstance(value, np.ndarray):
        return tuple(value.ravel().tolist())
    return value


def _invariance(con: Constraint) -> str | None:
    """How much of the armature's world matrix this constraint ignores with owner and target in world
    space, so that it may run in pose space instead: ``"affine"`` (any world matrix: replacing the
    transform or the location), ``"similarity"`` (uniform scale and rotation: comparing lengths),
    ``"proper"`` (without mirroring: turning by cross products), or None (it needs world space)."""
    t, get = con.type, con.get
    if t == "COPY_TRANSFORMS":
        return "affine" if get("mix_mode") == "REPLACE" and not get("remove_target_shear") else None
    if t == "COPY_LOCATION":
        plain = all(get(f"use_{c}") and not get(f"invert_{c}") for c in "xyz") and not get("use_offset")
        return "affine" if plain else None
    if t == "COPY_SCALE":
        axes = all(get(f"use_{c}") for c in "xyz")
        plain = get("power") == 1 and not get("use_offset") and (axes or not get("use_make_uniform"))
        return "similarity" if plain else None
    if t in ("STRETCH_TO", "DAMPED_TRACK", "LOCKED_TRACK"):
        return "proper"
    return None


def constraint_key(constraint: Constraint, targets: Mapping[str, Any], owner: Bone) -> tuple:
    """The discrete settings of a constraint: constraints (of bones in one stack, at one place in their
    constraint stacks) with equal keys are evaluated by one :class:`ConstraintStack`.

    The key holds the type, the owner and target spaces, whether the influence is 0 (the constraint is
    skipped: the key is ``("OFF",)``) or 1 (no blending), the type's discrete settings (mix modes, axis
    flags, volume modes, track axes, whether a Copy Scale power is 1 ...), the Euler orders it
    decomposes in (``AUTO`` resolved to the owner's), and per target: a bone or an object, whether
    ``head_tail`` is 0, in the local target spaces the :func:`solver.rig.bones.bone_key` of the target bone
    and its parent, for Armature constraints the weight's sign and the envelope options; and whether
    the ``CUSTOM`` space is a bone or an object.

    Parameters
    ----------
    constraint : Constraint
    targets : Mapping[str, Bone or TargetBone]
        The bones the constraint reads, and their parents (for the local target spaces).
    owner : Bone
        The bone that owns the constraint (its Euler order).

    Raises
    ------
    SolverError
        If the constraint is not modelled (:meth:`Constraint.unsupported`).
    """
    problem = constraint.unsupported()
    if problem is not None:
        raise SolverError(f"bone {owner.name!r}: {problem}")
    if constraint.influence == 0:
        return ("OFF",)
    t = constraint.type
    continuous = CONTINUOUS.get(t, ())
    settings = tuple(
        (k, _hashable(constraint.get(k))) for k in DEFAULTS[t] if k not in continuous and k != "euler_order"
    )
    derived: tuple = ()
    if t in ("COPY_ROTATION", "LIMIT_ROTATION"):
        order = constraint.get("euler_order")
        derived = (owner.euler_order if order == "AUTO" else order,)
    elif t == "CHILD_OF":
        derived = (owner.euler_order,)
    elif t == "COPY_SCALE":
        derived = (constraint.get("power") == 1,)
    what = f"constraint {constraint.name!r} of bone {owner.name!r}"
    slots = []
    for target in constraint.targets:
        if not target.subtarget:
            slots.append(("object", target.euler_order if t == "CHILD_OF" else None))
            continue
        bone = _bone_of(targets, target.subtarget, what)
        slot: tuple = ("bone", target.head_tail >= 1e-6)
        if constraint.target_space in _LOCAL_SPACES:
            parent = _bone_of(targets, bone.parent, what) if bone.parent else None
            slot += (bone_key(bone, parent),)
        if t == "CHILD_OF":
            slot += (bone.euler_order,)
        if t == "ARMATURE":
            envelope = constraint.get("use_bone_envelopes") or bone.use_envelope_multiply
            slot += (target.weight > 0, envelope, bone.envelope_distance == 0, bone.length != 0)
        slots.append(slot)
    custom = None
    if "CUSTOM" in (constraint.owner_space, constraint.target_space):
        custom = "bone" if constraint.space_subtarget else "object"
    return (
        t,
        constraint.owner_space,
        constraint.target_space,
        constraint.influence >= 1,
        settings,
        derived,
        tuple(slots),
        custom,
    )


def _column(values) -> np.ndarray:
    out = np.array(values, dtype=np.float64).reshape(len(values), 1, *np.shape(values[0]))
    out.setflags(write=False)
    return out


class Slot:
    """One target (or the custom space) of a :class:`ConstraintStack`, over the stack.

    Attributes
    ----------
    kind : str
        ``"bone"`` or ``"object"``.
    names : tuple of str or None
        The target bones (their poses are the stack's inputs).
    parent_names : tuple of (str or None) or None
        Their parents, when the target space needs their poses (local target spaces).
    matrix : (g, 1, 4, 4) or None
        The world matrices of object targets.
    head_tail : (g, 1) or None
        Where along the bones the targets are taken (None: at the heads).
    length : (g, 1) or None
        The target bones' rest lengths.
    stack : BoneStack or None
        The target bones under their parents (local target spaces).
    rest, rest_inverse : (g, 1, 4, 4) or None
        The target bones' rest matrices and their inverses.
    diff : tuple or None
        ``LOCAL_OWNER_ORIENT``'s change of frame (:func:`solver.rig.bones.owner_orientation`).
    """

    def __init__(self, kind: str):
        self.kind = kind
        self.names = None
        self.parent_names = None
        self.matrix = None
        self.head_tail = None
        self.length = None
        self.stack = None
        self.rest = None
        self.rest_inverse = None
        self.diff = None
        self.weight = None
        self.positive = True
        self.envelope = False
        self.envelope_data = None
        self.euler_order = "XYZ"


class ConstraintStack:
    """``g`` constraints with one :func:`constraint_key` (one per bone of a stack), their continuous
    settings as arrays (stack layout: ``(g, 1, ...)``).

    Build it with :meth:`of`. Its :attr:`inputs` name the bones whose poses :func:`stack_pose_bones`
    needs, per slot (the targets in order, then the ``CUSTOM`` space's bone), and :attr:`parent_inputs`
    their parents where the target space needs those.

    Attributes
    ----------
    type, owner_space, target_space : str
    key : tuple
    names : tuple of str
        The constraints' names.
    influence : (g, 1)
    full, off : bool
        Influence 1 (no blending), influence 0 (skipped).
    order : str
        The Euler order the type decomposes the owner in (resolved ``AUTO``), else ``XYZ``.
    slots : tuple of Slot
        The targets; ``custom`` the ``CUSTOM`` space (a Slot) or None.
    """

    def __init__(self):
        self.values: dict[str, np.ndarray] = {}
        self.settings: dict[str, Any] = {}
        self.slots: tuple[Slot, ...] = ()
        self.custom: Slot | None = None
        self.inputs: tuple = ()
        self.parent_inputs: tuple = ()
        self.invariance: str | None = None
        self.order = "XYZ"
        self.bulge_one = False

    @classmethod
    def of(cls, constraints: Sequence[Constraint], owners: Sequence[Bone], targets: Mapping[str, Any]):
        """The stack of ``constraints``, one per bone of ``owners``, all with one :func:`constraint_key`.

        ``targets`` maps the names of the bones they read (and of those bones' parents, for the local
        target spaces) to their rest data (:class:`solver.rig.bones.Bone` or :class:`TargetBone`).
        """
        constraints, owners = tuple(constraints), tuple(owners)
        if not constraints or len(constraints) != len(owners):
            raise SolverError("a constraint stack needs one owner bone per constraint, and one constraint")
        keys = {constraint_key(c, targets, o) for c, o in zip(constraints, owners, strict=True)}
        if len(keys) != 1:
            raise SolverError(
                f"constraints {', '.join(repr(c.name) for c in constraints[:4])} differ in their discrete "
                f"settings ({len(keys)} kinds); stack them by constraint_key"
            )
        self = cls()
        self.key = keys.pop()
        first = constraints[0]
        self.type = first.type
        self.names = tuple(c.name for c in constraints)
        self.owner_space, self.target_space = first.owner_space, first.target_space
        self.size = len(constraints)
        self.off = self.key == ("OFF",)
        self.influence = _column([c.influence for c in constraints])
        self.full = bool(self.off or self.key[3])
        if self.off:
            return self
        t = first.type
        for k in DEFAULTS[t]:
            if k in CONTINUOUS.get(t, ()):
                self.values[k] = _column([c.get(k) for c in constraints])
            else:
                self.settings[k] = first.get(k)
        if t in ("COPY_ROTATION", "LIMIT_ROTATION", "CHILD_OF"):
            self.order = self.key[5][0]
        self.invariance = _invariance(first)
        what = f"constraint {first.name!r} of bone {owners[0].name!r}"
        slots = []
        for j in range(len(first.targets)):
            column = [c.targets[j] for c in constraints]
            slots.append(self._slot(column, owners, targets, what))
        self.slots = tuple(slots)
        if self.key[7] == "bone":
            custom = Slot("bone")
            custom.names = tuple(c.space_subtarget for c in constraints)
            self.custom = custom
        elif self.key[7] == "object":
            custom = Slot("object")
            matrices = [_EYE4 if c.space_matrix is None else c.space_matrix for c in constraints]
            custom.matrix = _column(matrices)
            self.custom = custom
        self._prepare()
        read = self.slots + ((self.custom,) if self.custom is not None and self.custom.kind == "bone" else ())
        self.inputs = tuple(s.names for s in read)
        self.parent_inputs = tuple(s.parent_names for s in read)
        return self

    def _slot(self, column, owners, targets, what) -> Slot:
        first = column[0]
        if not first.subtarget:
            slot = Slot("object")
            slot.matrix = _column([t.matrix for t in column])
            slot.euler_order = first.euler_order
            slot.weight = _column([t.weight for t in column])
            return slot
        slot = Slot("bone")
        slot.names = tuple(t.subtarget for t in column)
        bones = [_bone_of(targets, n, what) for n in slot.names]
        slot.euler_order = bones[0].euler_order
        slot.length = _column([b.length for b in bones])
        if first.head_tail >= 1e-6:
            slot.head_tail = _column([t.head_tail for t in column])
        space = self.target_space
        if space in _LOCAL_SPACES:
            parents = [_bone_of(targets, b.parent, what) if b.parent else None for b in bones]
            slot.stack = BoneStack.of(bones, parents)
            if not slot.stack.root:
                slot.parent_names = tuple(b.parent for b in bones)
            if space == "LOCAL_OWNER_ORIENT":
                rests = [b.matrix_local for b in bones]
                slot.diff = owner_orientation(rests, [o.matrix_local for o in owners])
        if space == "LOCAL_WITH_PARENT" or self.type == "ARMATURE":
            slot.rest = _column([b.matrix_local for b in bones])
            slot.rest_inverse = _column([np.linalg.inv(b.matrix_local) for b in bones])
        if self.type == "ARMATURE":
            slot.weight = _column([t.weight for t in column])
            slot.positive = first.weight > 0
            slot.envelope = bool(self.settings["use_bone_envelopes"] or bones[0].use_envelope_multiply)
            slot.envelope_data = (
                _column([b.head_local for b in bones]),
                _column([b.tail_local for b in bones]),
                _column([b.head_radius for b in bones]),
                _column([b.tail_radius for b in bones]),
                _column([b.envelope_distance for b in bones]),
            )
        return slot

    def _prepare(self):
        """Constants derived from the continuous settings."""
        v = self.values
        self.bulge_one = False
        if self.type == "STRETCH_TO":
            self.bulge_one = bool(np.all(v["bulge"] == 1.0))
            bmax = np.maximum(v["bulge_max"], 1.0)
            rng = bmax - 1.0
            v["_bmax"], v["_bmax_range"] = bmax, rng
            v["_bmax_fac"] = np.where(rng > 0, 1.0 / np.where(rng > 0, rng, 1.0), 0.0)
            bmin = np.minimum(np.maximum(v["bulge_min"], 0.0), 1.0)
            rng = 1.0 - bmin
            v["_bmin"], v["_bmin_range"] = bmin, rng
            v["_bmin_fac"] = np.where(rng > 0, 1.0 / np.where(rng > 0, rng, 1.0), 0.0)
        elif self.type == "CHILD_OF":
            inverse = v["inverse_matrix"]
            v["_inverse_loc"] = inverse[..., :3, 3]
            v["_inverse_euler"] = matrix_to_euler(inverse, self.order)
            v["_inverse_size"] = matrix_to_size(inverse)

    # ------------------------------------------------------------------ what a caller gathers

    @property
    def replaces(self) -> bool:
        """Whether the result ignores the owner's transform before it: Copy Transforms with Replace at
        influence 1, owner and target in world (or pose) space."""
        return (
            not self.off
            and self.full
            and self.type == "COPY_TRANSFORMS"
            and self.invariance == "affine"
            and self.owner_space == self.target_space
            and self.owner_space in ("WORLD", "POSE")
        )

    def in_pose_space(self, world: World) -> bool:
        """Whether this stack may be evaluated with the owner and targets in pose space: both spaces are
        POSE, or both WORLD and the world matrix is one the type ignores."""
        if self.owner_space != self.target_space or self.owner_space not in ("WORLD", "POSE"):
            return False
        if self.owner_space == "POSE" or world.identity:
            return True
        need = self.invariance
        if need == "affine":
            return True
        if need == "similarity":
            return world.similarity
        return need == "proper" and world.proper

    def get(self, key: str):
        """A discrete setting, or a continuous one as a (g, 1) array."""
        if key in self.settings:
            return self.settings[key]
        return self.values[key]


# ----------------------------------------------------------------------------------------------------
# The constraint types' ``*_evaluate`` functions, stacked. Each takes the owner matrix (in the owner
# space) and the target matrices (in the target space), stack layout, and returns the new owner matrix.


@dataclass
class _Context:
    owner: BoneStack
    world: World
    order: str
    poses: list  # the target bones' pose matrices, per slot (Armature)


def _copy_location(cs, cob, tars, ctx):
    T = tars[0]
    use = [cs.get(f"use_{c}") for c in "xyz"]
    invert = [cs.get(f"invert_{c}") for c in "xyz"]
    offset = cs.get("use_offset")
    if all(use) and not any(invert) and not offset:
        return with_translation(cob, T[..., :3, 3])
    loc = cob[..., :3, 3]
    sign = np.where(invert, -1.0, 1.0)
    copied = T[..., :3, 3] * sign + (loc if offset else 0.0)
    return with_translation(cob, np.where(use, copied, loc))


def _rotate_euler(eul, order, axis: int, angle):
    unit = np.zeros((*np.shape(angle), 3))
    unit = unit.astype(np.result_type(unit, angle))
    unit[..., axis] = angle
    total = euler_to_matrix(eul, order) @ euler_to_matrix(unit, order)
    return matrix_to_euler(total, order)


def _copy_rotation(cs, cob, tars, ctx):
    loc, oldrot, size = decompose(cob)
    order = cs.order
    mat = orthogonalize_stable(tars[0], 1, unit=True)
    mix = cs.get("mix_mode")
    use = [cs.get(f"use_{c}") for c in "xyz"]
    invert = [cs.get(f"invert_{c}") for c in "xyz"]
    if mix == "REPLACE" and all(use) and not any(invert):
        newrot = _replaced_rotation(mat, order)
        if newrot is not None:
            return compose(loc, newrot, size)
    obeul = matrix_to_euler(cob, order)
    eul = matrix_to_compatible_euler(mat, obeul, order)
    legacy = mix == "OFFSET"
    defeul = obeul if mix in ("OFFSET", "REPLACE") else np.zeros_like(obeul)
    shape = np.broadcast_shapes(eul.shape, obeul.shape)
    eul = np.array(np.broadcast_to(eul, shape), dtype=np.result_type(eul, obeul))
    for a in range(3):
        if not use[a]:
            eul[..., a] = np.broadcast_to(defeul, eul.shape)[..., a]
        else:
            if legacy:
                eul = _rotate_euler(eul, order, a, obeul[..., a])
            if invert[a]:
                eul[..., a] = -eul[..., a]
    if mix == "ADD":
        eul = eul + obeul
    eul = compatible_euler(eul, obeul)
    newrot = euler_to_matrix(eul, order)
    if mix == "BEFORE":
        newrot = newrot @ oldrot
    elif mix == "AFTER":
        newrot = oldrot @ newrot
    return compose(loc, newrot, size)


def _replaced_rotation(mat, order):
    """The rotation Copy Rotation (Replace, every axis, no inversion) puts in, or None near gimbal lock.

    Blender turns the target's orthonormalized matrix into Euler angles and back. Away from gimbal lock
    both Euler solutions are ``mat3_normalized_to_eulo2``'s first one up to turns, which reads the
    matrix's entries through three normalized pairs: ``(cos, sin)`` of the three angles. The rotation is
    built from those pairs directly (no angles), which is that round trip, derivatives included, also
    where ``mat`` is not quite orthonormal.
    """
    i, j, k = order_axes(order)
    M = mat[..., :3, :3]

    def B(a, b):  # Blender's mat[a][b]
        return M[..., b, a]

    cy_sq = B(i, i) * B(i, i) + B(i, j) * B(i, j)
    if cy_sq.real.min() <= EULER_HYPOT_EPSILON**2 * 4:
        return None
    cy = np.sqrt(cy_sq)
    parity = -1.0 if order in ("XZY", "YXZ", "ZYX") else 1.0
    hi_sq = B(j, k) * B(j, k) + B(k, k) * B(k, k)
    if not hi_sq.real.min() > 0:
        return None
    h_i = np.sqrt(hi_sq)
    h_j = np.sqrt(B(i, k) * B(i, k) + cy_sq)
    pairs = [
        (i, B(k, k) / h_i, parity * B(j, k) / h_i),
        (j, cy / h_j, -parity * B(i, k) / h_j),
        (k, B(i, i) / cy, parity * B(i, j) / cy),
    ]
    Rs = [_axis_rotation(a, c, s) for a, c, s in pairs]
    return Rs[2] @ Rs[1] @ Rs[0]


# Elementary rotations about axis a: ONE[a] + cos COS[a] + sin SIN[a] (rotations.axis_rotation).
_AXIS_ONE = np.zeros((3, 3, 3))
_AXIS_COS = np.zeros((3, 3, 3))
_AXIS_SIN = np.zeros((3, 3, 3))
for _a in range(3):
    _i1, _i2 = (_a + 1) % 3, (_a + 2) % 3
    _AXIS_ONE[_a, _a, _a] = 1.0
    _AXIS_COS[_a, _i1, _i1] = _AXIS_COS[_a, _i2, _i2] = 1.0
    _AXIS_SIN[_a, _i2, _i1], _AXIS_SIN[_a, _i1, _i2] = 1.0, -1.0


def _power(x, p):
    x = np.asarray(x)
    ok = x.real > 0
    return np.where(ok, np.exp(p * np.log(np.where(ok, x, 1.0))), 0.0)


def _copy_scale(cs, cob, tars, ctx):
    T = tars[0]
    axes = [cs.get(f"use_{c}") for c in "xyz"]
    uniform = cs.get("use_make_uniform")
    power1 = cs.key[5][0]
    offset = cs.get("use_offset")
    if all(axes) and not uniform and power1 and not offset:
        target = column_norms_squared(T[..., :3, :3])
        owner = column_norms_squared(cob[..., :3, :3])
        if not owner.real.min() > 0:
            owner = np.where(owner.real != 0, owner, 1.0)
        return rescale(cob, np.sqrt(target / owner))
    obsize = matrix_to_size(cob)
    if uniform:
        if all(axes):
            total = det3(T)
            total = np.where(total.real < 0, -total, total)
        else:
            size = matrix_to_size(T)
            total = np.ones(size.shape[:-1], dtype=size.dtype)
            for a in range(3):
                if axes[a]:
                    total = total * size[..., a]
        size = np.repeat(cbrt_abs(total)[..., None], 3, axis=-1)
    else:
        size = matrix_to_size(T)
    if not power1:
        size = _power(size, cs.get("power"))
    if offset:
        size = size + obsize - 1.0 if cs.get("use_add") else size * obsize
    ok = obsize.real != 0
    factor = np.where(ok, size / np.where(ok, obsize, 1.0), 1.0)
    factor = np.where(np.array(axes) | uniform, factor, 1.0)
    return rescale(cob, factor)


def _aligned_scale(A, B):
    """``mul_m4_m4m4_aligned_scale``."""
    _la, ra, sa = decompose(A)
    lb, rb, sb = decompose(B)
    return compose(transform_point(A, lb), ra @ rb, sa * sb)


def _split_channels(A, B):
    """``mul_m4_m4m4_split_channels``."""
    la, ra, sa = decompose(A)
    lb, rb, sb = decompose(B)
    return compose(la + lb, ra @ rb, sa * sb)


def _copy_transforms(cs, cob, tars, ctx):
    T = tars[0]
    if cs.get("remove_target_shear"):
        T = orthogonalize_stable(T, 1, unit=False)
    mix = cs.get("mix_mode")
    if mix == "REPLACE":
        return T
    if mix == "BEFORE_FULL":
        return matmul(T, cob)
    if mix == "AFTER_FULL":
        return matmul(cob, T)
    if mix == "BEFORE":
        return _aligned_scale(T, cob)
    if mix == "AFTER":
        return _aligned_scale(cob, T)
    if mix == "BEFORE_SPLIT":
        return _split_channels(T, cob)
    return _split_channels(cob, T)


def damped_track(matrix, target_vector, track_axis: int):
    """``damptrack_do_transform``: turn ``matrix`` (..., 4, 4) by the smallest rotation that points its
    ``track_axis`` (index into :data:`TRACK_AXES`) along ``target_vector`` (..., 3); location kept.

    Blender turns about ``normalize(a × b)`` by ``acos(a · b)`` (``asin`` when the turn is small); away
    from opposite directions this is the rotation ``(a · b) I + [a × b]× + (a × b)(a × b)ᵀ / (1 + a · b)``,
    computed so.
    """
    matrix = np.asarray(matrix)
    tarvec, tarlen = normalize(target_vector)
    shape = np.broadcast_shapes(matrix.shape[:-2], tarvec.shape[:-1])
    M3 = matrix[..., :3, :3]
    sign = 1.0 if track_axis < 3 else -1.0
    raw = M3[..., :, track_axis % 3]
    obvec, oblen = normalize(raw)
    cos = dot(obvec, tarvec) * sign
    if tarlen.real.min() > 0 and oblen.real.min() > 0 and cos.real.min() > -0.5:
        v = cross(obvec, tarvec) * sign
        outer = v[..., :, None] * (v / (1.0 + cos)[..., None])[..., None, :]
        R = cos[..., None, None] * np.eye(3) + skew(v) + outer
        out = np.array(np.broadcast_to(matrix, (*shape, 4, 4)), dtype=np.result_type(matrix, R))
        out[..., :3, :3] = R @ M3
        return out
    return _damped_track_general(np.broadcast_to(matrix, (*shape, 4, 4)), tarvec, tarlen, track_axis)


def _damped_track_general(matrix, tarvec, tarlen, track_axis):
    M3 = matrix[..., :3, :3]
    obvec, oblen = normalize(M3 @ _TRACK_DIRECTIONS[track_axis])
    obvec = np.where((oblen.real == 0)[..., None], _TRACK_DIRECTIONS[track_axis], obvec)
    raxis = cross(obvec, tarvec)
    cos = dot(obvec, tarvec)
    rangle = analytic.acos(np.where(cos.real > 1, 1.0, np.where(cos.real < -1, -1.0, cos)))
    raxis, norm = normalize(raxis)
    opposite = norm.real < FLT_EPSILON
    keep = (tarlen.real == 0) | (opposite & (np.abs(rangle.real) < np.pi - 0.01))
    if np.any(opposite & ~keep):
        other = normalize(cross(obvec, M3 @ _TRACK_DIRECTIONS[(track_axis + 1) % 6]))
        raxis = np.where(opposite[..., None], other[0], raxis)
        rangle = np.where(opposite, np.pi, rangle)
        keep = keep | (opposite & (other[1].real == 0))
    small = ~opposite & (norm.real < 0.1)
    if np.any(small):
        asin = analytic.asin(np.where(small, norm, 0.0))
        rangle = np.where(small, np.where(rangle.real > np.pi / 2, np.pi - asin, asin), rangle)
    R = axis_angle_matrix(raxis, np.sin(rangle), np.cos(rangle))
    parallel = opposite & (cos.real > 0) & (tarlen.real > 0)
    if np.any(parallel):  # a turn below FLT_EPSILON: taken (continuously) rather than skipped
        v = cross(obvec, tarvec)
        outer = v[..., :, None] * (v / (1.0 + cos)[..., None])[..., None, :]
        turn = cos[..., None, None] * np.eye(3) + skew(v) + outer
        R = np.where(parallel[..., None, None], turn, R)
        keep = keep & ~parallel
    out = np.array(matrix, dtype=np.result_type(matrix, R))
    out[..., :3, :3] = R @ M3
    return np.where(keep[..., None, None], matrix, out)


def _damped_track(cs, cob, tars, ctx):
    axis = TRACK_AXES.index(cs.get("track_axis"))
    return damped_track(cob, tars[0][..., :3, 3] - cob[..., :3, 3], axis)


def _interpf(target, origin, fac):
    return fac * target + (1.0 - fac) * origin


def _bulge_factors(cs, ratio):
    """(sx, sz) of Stretch To's volume preservation for ``rest / dist`` ratios ``ratio`` (None: 1)."""
    v = cs.values
    volume = cs.get("volume")
    if volume == "NO_VOLUME":
        return None, None
    bulge = ratio if cs.bulge_one else np.exp(v["bulge"] * np.log(ratio))
    smooth = v["bulge_smooth"]
    if cs.get("use_bulge_max"):
        bmax, rng = v["_bmax"], v["_bmax_range"]
        hard = np.where(bulge.real < bmax, bulge, bmax)
        soft = 1.0 + rng * analytic.atan2((bulge - 1.0) * v["_bmax_fac"], 1.0) / (np.pi / 2)
        bulge = np.where(bulge.real > 1.0, _interpf(soft, hard, smooth), bulge)
    if cs.get("use_bulge_min"):
        bmin, rng = v["_bmin"], v["_bmin_range"]
        hard = np.where(bulge.real > bmin, bulge, bmin)
        soft = 1.0 - rng * analytic.atan2((1.0 - bulge) * v["_bmin_fac"], 1.0) / (np.pi / 2)
        bulge = np.where(bulge.real < 1.0, _interpf(soft, hard, smooth), bulge)
    if volume == "VOLUME_XZX":
        sx = np.sqrt(bulge)
        return sx, sx
    if volume == "VOLUME_X":
        return bulge, None
    if volume == "VOLUME_Z":
        return None, bulge
    raise SolverError(f"Stretch To constraint {cs.names[0]!r}: unknown volume mode {volume!r}")


def _stretch_swing(cs, cob, T):
    """Stretch To with ``SWING_Y`` when nothing degenerates: Y turned onto the target by the smallest
    rotation, ``(a · b) I + [a × b]× + (a × b)(a × b)ᵀ / (1 + a · b)``, which on the X and Z axes (made
    perpendicular to Y, the shear removed) is ``w - (a + b)(b · w) / (1 + a · b)``; Y becomes the
    vector to the target over the rest length. None when an axis or the target vector vanishes, X and
    Z are sheared beyond 1e-4 or the turn is beyond 120°: then the general port runs."""
    A = cob[..., :3, :3]
    h = cob[..., :3, 3]
    Y = A[..., :, 1]
    YA = (Y[..., None, :] @ A)[..., 0, :]  # Y·X, Y·Y, Y·Z
    yy = YA[..., 1]
    d = T[..., :3, 3] - h
    dd = dot(d, d)
    if not (yy.real.min() > 0 and dd.real.min() > 0):
        return None
    XZ = A[..., :, ::2] - Y[..., :, None] * (YA[..., ::2] / yy[..., None])[..., None, :]
    n2 = column_norms_squared(XZ).real
    xz = dot(XZ[..., 0], XZ[..., 1]).real
    ylen, dist = np.sqrt(yy), np.sqrt(dd)
    c = dot(Y, d) / (ylen * dist)
    sheared = (xz * xz - 1e-8 * n2[..., 0] * n2[..., 1]).max() > 0
    if not (n2.min() > 1e-35 and c.real.min() > -0.5) or sheared:
        return None
    coef = (d[..., None, :] @ XZ) / (dist * (1.0 + c))[..., None, None]
    RXZ = XZ - (Y / ylen[..., None] + d / dist[..., None])[..., :, None] * coef
    rest = cs.values["rest_length"]
    sx, sz = _bulge_factors(cs, rest * ylen / dist)
    out = np.empty((*RXZ.shape[:-2], 4, 4), dtype=RXZ.dtype)
    out[..., 3, :] = _LAST_ROW
    out[..., :3, 3] = h
    out[..., :3, 1] = d / rest[..., None]
    if sx is None and sz is None:
        out[..., :3, ::2] = RXZ
    else:
        out[..., :3, 0] = RXZ[..., 0] if sx is None else RXZ[..., 0] * sx[..., None]
        out[..., :3, 2] = RXZ[..., 1] if sz is None else RXZ[..., 1] * sz[..., None]
    return out


def _stretch_to(cs, cob, tars, ctx):
    T = tars[0]
    plane = cs.get("keep_axis")
    if plane == "SWING_Y":
        out = _stretch_swing(cs, cob, T)
        if out is not None:
            return out
        cob = orthogonalize_stable(cob, 1, unit=False)
    cob, size = normalize_axes(cob)
    xx, zz = cob[..., :3, 0], cob[..., :3, 2]
    vec, dist = normalize(T[..., :3, 3] - cob[..., :3, 3])
    dist = dist / size[..., 1]
    rest = cs.values["rest_length"]
    scale_y = dist / rest
    sx, sz = _bulge_factors(cs, rest / dist)
    one = np.ones_like(scale_y)
    factors = np.broadcast_arrays(one if sx is None else sx, scale_y, one if sz is None else sz)
    size = size * np.stack(factors, -1)
    if plane == "SWING_Y":
        cob = damped_track(cob, vec, 1)
    else:
        cob = np.array(np.broadcast_to(cob, (*vec.shape[:-1], 4, 4)), dtype=np.result_type(cob, vec))
        cob[..., :3, 1] = vec
        if plane == "PLANE_X":
            orth, _ = normalize(cross(xx, vec))
            cob[..., :3, 2] = orth
            cob[..., :3, 0] = normalize(cross(vec, orth))[0]
        else:
            orth, _ = normalize(cross(zz, vec))
            cob[..., :3, 0] = -orth
            cob[..., :3, 2] = normalize(cross(vec, orth))[0]
    return rescale(cob, size)


def _child_of(cs, cob, tars, ctx):
    T = tars[0]
    v = cs.values
    flags = {k: cs.get(k) for k in DEFAULTS["CHILD_OF"] if k.startswith("use_")}
    target_order = cs.slots[0].euler_order
    if all(flags.values()):
        parmat, invmat = T, v["inverse_matrix"]
    else:
        loc, eul, size = T[..., :3, 3], matrix_to_euler(T, target_order), matrix_to_size(T)
        loco, eulo, sizeo = v["_inverse_loc"], v["_inverse_euler"], v["_inverse_size"]
        loc_on = np.array([flags[f"use_location_{c}"] for c in "xyz"])
        rot_on = np.array([flags[f"use_rotation_{c}"] for c in "xyz"])
        size_on = np.array([flags[f"use_scale_{c}"] for c in "xyz"])
        loc, loco = np.where(loc_on, loc, 0.0), np.where(loc_on, loco, 0.0)
        eul, eulo = np.where(rot_on, eul, 0.0), np.where(rot_on, eulo, 0.0)
        size, sizeo = np.where(size_on, size, 1.0), np.where(size_on, sizeo, 1.0)
        parmat = _loc_euler_size(loc, eul, size, target_order)
        invmat = _loc_euler_size(loco, eulo, sizeo, ctx.order)
    out = matmul(matmul(parmat, invmat), cob)
    keep = [not flags[f"use_location_{c}"] for c in "xyz"]
    if any(keep):
        out = with_translation(out, np.where(keep, cob[..., :3, 3], out[..., :3, 3]))
    return out


def _basis_cross(n, m):
    d = n - m
    return 1 if d in (1, -2) else (-1 if d in (-1, 2) else 0)


def _track_to(cs, cob, tars, ctx):
    T = tars[0]
    axis = TRACK_AXES.index(cs.get("track_axis"))
    up = ("UP_X", "UP_Y", "UP_Z").index(cs.get("up_axis"))
    size = matrix_to_size(cob)
    shape = np.broadcast_shapes(np.shape(cob)[:-2], np.shape(T)[:-2])
    out = np.array(np.broadcast_to(cob, (*shape, 4, 4)), dtype=np.result_type(cob, T))
    out[..., :3, :3] = np.broadcast_to(size[..., None, :] * np.eye(3), (*shape, 3, 3))
    vec = out[..., :3, 3] - T[..., :3, 3]
    n, length = normalize(vec)
    n = np.where((length.real == 0)[..., None], np.array([0.0, 0.0, 1.0]), n)
    if axis > 2:
        axis -= 3
    else:
        n = -n
    u = np.broadcast_to(T[..., :3, 2], n.shape) if cs.get("use_target_z") else np.array([0.0, 0.0, 1.0])
    nn = dot(n, n)
    proj = u - n * (dot(u, n) / np.where(nn.real != 0, nn, 1.0))[..., None]
    proj, plen = normalize(proj)
    proj = np.where((plen.real == 0)[..., None], np.array([0.0, 1.0, 0.0]), proj)
    right, _ = normalize(cross(proj, n))
    if axis == up:
        return out
    m = np.zeros((*n.shape[:-1], 3, 3), dtype=n.dtype)
    m[..., :, 3 - axis - up] = _basis_cross(axis, up) * right
    m[..., :, up] = proj
    m[..., :, axis] = n
    out[..., :3, :3] = m @ out[..., :3, :3]
    return out


def _locked_track(cs, cob, tars, ctx):
    T = tars[0]
    track = TRACK_AXES.index(cs.get("track_axis"))
    lock = ("LOCK_X", "LOCK_Y", "LOCK_Z").index(cs.get("lock_axis"))
    sign = -1.0 if track > 2 else 1.0
    t = track % 3
    shape = np.broadcast_shapes(np.shape(cob)[:-2], np.shape(T)[:-2])
    cob = np.broadcast_to(cob, (*shape, 4, 4))
    if t == lock:
        return np.array(cob)
    vec = T[..., :3, 3] - cob[..., :3, 3]
    axis = cob[..., :3, lock]
    aa = dot(axis, axis)
    vec2 = axis * (dot(vec, axis) / np.where(aa.real != 0, aa, 1.0))[..., None]
    tot = np.zeros((*shape, 3, 3), dtype=np.result_type(cob, T))
    tot[..., :, t] = sign * normalize(vec - vec2)[0]
    tot[..., :, lock] = normalize(axis)[0]
    third = 3 - t - lock
    tot[..., :, third] = cross(tot[..., :, (third + 1) % 3], tot[..., :, (third + 2) % 3])
    unit = _unit3(cob)
    tot = tot @ inverse3(unit)
    tot = np.where(
        (det3(tot).real == 0)[..., None, None],
        np.eye(3),
        tot,
    )
    out = np.array(cob, dtype=tot.dtype)
    out[..., :3, :3] = tot @ cob[..., :3, :3]
    return out


def _wrap_angle(angle):
    b = angle * (0.5 / np.pi) + 0.5
    return (b - np.floor(b.real) - 0.5) * (2.0 * np.pi)


def _clamp_angle(angle, lo, hi):
    """``clamp_angle``: ``angle`` clamped into the directed range ``[lo, hi]`` on the circle (``lo``, ``hi``
    floats or arrays broadcasting against ``angle``)."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    mn = _wrap_angle(lo - angle)
    mx = _wrap_angle(hi - angle)
    simple = mn.real < mx.real
    clamped = np.where(mn.real > 0, mn, np.where(mx.real < 0, mx, 0.0))
    inside = (mx.real >= 0) | (mn.real <= 0)
    closest = np.where(np.abs(mx.real) < np.abs(mn.real), mx, mn)
    out = angle + np.where(simple, clamped, np.where(inside, 0.0, closest))
    out = np.where(hi <= lo, lo + 0.0 * angle, out)
    return np.where(hi - lo >= 2 * np.pi, angle, out)


def _limit_rotation(cs, cob, tars, ctx):
    cob = orthogonalize_stable(cob, 1, unit=False)
    axes = [cs.get(f"use_limit_{c}") for c in "xyz"]
    if not any(axes):
        return cob
    order = cs.order
    loc, size = cob[..., :3, 3], matrix_to_size(cob)
    eul = np.array(matrix_to_euler(cob, order))
    for a, c in enumerate("xyz"):
        if not axes[a]:
            continue
        lo, hi = cs.get(f"min_{c}"), cs.get(f"max_{c}")
        if cs.get("use_legacy_behavior"):
            e = eul[..., a]
            eul[..., a] = np.where(e.real < lo, lo, np.where(e.real > hi, hi, e))
        else:
            eul[..., a] = _clamp_angle(eul[..., a], lo, hi)
    return _loc_euler_size(loc, eul, size, order)


def _limit_location(cs, cob, tars, ctx):
    loc = cob[..., :3, 3]
    components = []
    for a, c in enumerate("xyz"):
        v = loc[..., a]
        if cs.get(f"use_min_{c}"):
            lo = cs.get(f"min_{c}")
            v = np.where(v.real < lo, lo, v)
        if cs.get(f"use_max_{c}"):
            hi = cs.get(f"max_{c}")
            v = np.where(v.real > hi, hi, v)
        components.append(v)
    return with_translation(cob, np.stack(np.broadcast_arrays(*components), -1))


def _limit_scale(cs, cob, tars, ctx):
    obsize = matrix_to_size(cob)
    factors = []
    for a, c in enumerate("xyz"):
        s = obsize[..., a]
        if cs.get(f"use_min_{c}"):
            lo = cs.get(f"min_{c}")
            s = np.where(s.real < lo, lo, s)
        if cs.get(f"use_max_{c}"):
            hi = cs.get(f"max_{c}")
            s = np.where(s.real > hi, hi, s)
        ok = obsize[..., a].real != 0
        factors.append(np.where(ok, s / np.where(ok, obsize[..., a], 1.0), 1.0))
    return rescale(cob, np.stack(np.broadcast_arrays(*factors), -1))


def distfactor_to_bone(co, head, tail, rad_head, rad_tail, rdist):
    """(...) ``distfactor_to_bone``: envelope weight of point ``co`` (..., 3) for a bone ``head → tail``
    ((3,) or (..., 3); radii and distance: floats or arrays broadcasting against ``co``'s leading
    dimensions)."""
    co = np.asarray(co)
    rad_head, rad_tail, rdist = (np.asarray(x, dtype=np.float64) for x in (rad_head, rad_tail, rdist))
    bdelta, length = normalize(np.asarray(tail) - np.asarray(head))
    pdelta = co - head
    a = dot(bdelta, pdelta)
    hsqr = dot(pdelta, pdelta)
    d_head = dot(co - head, co - head)
    d_tail = dot(co - tail, co - tail)
    mid = hsqr - a * a
    has = length.real != 0
    frac = np.where(has, a / np.where(has, length, 1.0), 0.0)
    rad_mid = np.where(has, frac * rad_tail + (1.0 - frac) * rad_head, rad_head + 0.0 * a)
    before, after = a.real < 0, a.real > length.real
    dist_sq = np.where(before, d_head, np.where(after, d_tail, mid))
    rad = np.where(before, rad_head, np.where(after, rad_tail, rad_mid))
    inside = dist_sq.real < (rad * rad).real
    lim = (rad + rdist) ** 2
    outside = dist_sq.real >= lim.real
    e = np.sqrt(np.where(dist_sq.real > 0, dist_sq, 1.0)) - rad
    safe = np.where(rdist == 0, 1.0, rdist)
    smooth = np.where(inside, 1.0, np.where(outside, 0.0, 1.0 - e * e / (safe * safe)))
    return np.where(rdist == 0, np.where(inside, 1.0, 0.0), smooth)


def _orthogonalize_y(M):
    """``orthogonalize_m4(M, 1)`` (the non-stable one) on a (..., 4, 4)."""
    M = np.array(M)
    size = matrix_to_size(M)
    R0, R1, R2 = (M[..., :3, i] for i in range(3))
    R1 = normalize(R1)[0]
    first = dot(R1, R0).real < 1
    second = ~first & (dot(R0, R2).real < 1)
    a2 = normalize(cross(R0, R1))[0]
    a0 = cross(R1, a2)
    b0 = normalize(cross(R1, R2))[0]
    b2 = cross(b0, R1)
    vec = np.stack([R1[..., 1], R1[..., 2], R1[..., 0]], -1)
    c0 = normalize(cross(R1, vec))[0]
    c2 = cross(c0, R1)
    new0 = np.where(first[..., None], a0, np.where(second[..., None], b0, c0))
    new2 = np.where(first[..., None], a2, np.where(second[..., None], b2, c2))
    M[..., :3, 0], M[..., :3, 1], M[..., :3, 2] = new0, R1, new2
    return rescale(M, size)


def _to_dual_quaternion(basemat, mat):
    """``mat4_to_dquat`` (always taking its scaled branch, equal in value to the other): (quat (..., 4),
    trans (..., 4), scale (..., 4, 4))."""
    baseRS = matmul(mat, basemat)
    basequat = matrix_to_quaternion(_orthogonalize_y(baseRS))
    baseR = np.zeros(baseRS.shape, dtype=baseRS.dtype)
    baseR[..., :3, :3] = quaternion_to_matrix(basequat)
    baseR[..., :3, 3] = baseRS[..., :3, 3]
    baseR[..., 3, 3] = 1.0
    baseinv = inverse_affine(basemat)
    R = matmul(baseR, baseinv)
    S = matmul(inverse_affine(baseR), baseRS)
    scale = matmul(matmul(basemat, S), baseinv)
    q = matrix_to_quaternion(R)
    t = R[..., :3, 3]
    trans = np.stack(
        [
            -0.5 * (t[..., 0] * q[..., 1] + t[..., 1] * q[..., 2] + t[..., 2] * q[..., 3]),
            0.5 * (t[..., 0] * q[..., 0] + t[..., 1] * q[..., 3] - t[..., 2] * q[..., 2]),
            0.5 * (-t[..., 0] * q[..., 3] + t[..., 1] * q[..., 0] + t[..., 2] * q[..., 1]),
            0.5 * (t[..., 0] * q[..., 2] - t[..., 1] * q[..., 1] + t[..., 2] * q[..., 0]),
        ],
        -1,
    )
    return q, trans, scale


def _armature(cs, cob, tars, ctx):
    world, iworld = ctx.world.matrix, ctx.world.inverse
    if cs.get("use_current_location"):
        wco = cob[..., :3, 3]
    else:
        wco = transform_point(world, ctx.owner.rest[..., :3, 3])
    preserve = cs.get("use_deform_preserve_volume")
    total = 0.0
    sum_mat = 0.0
    dq_quat = dq_trans = dq_scale = None
    dq_scale_weight = 0.0
    for slot, pose in zip(cs.slots, ctx.poses, strict=True):
        if not slot.positive:
            continue
        weight = slot.weight
        co = transform_point(iworld, wco)
        if slot.envelope:
            head, tail, rad_head, rad_tail, rdist = slot.envelope_data
            weight = weight * distfactor_to_bone(co, head, tail, rad_head, rad_tail, rdist)
        chan = matmul(pose, slot.rest_inverse)
        mat = matmul(matmul(world, chan), iworld)
        weight = np.asarray(weight)
        nonzero = weight.real != 0
        if preserve:
            basemat = orthogonalize_stable(matmul(world, slot.rest), 1, unit=True)
            q, trans, scale = _to_dual_quaternion(basemat, mat)
            dst = transform_point(scale, wco) - wco
            trans = trans + 0.5 * np.stack(
                [
                    -(q[..., 1] * dst[..., 0] + q[..., 2] * dst[..., 1] + q[..., 3] * dst[..., 2]),
                    q[..., 0] * dst[..., 0] + q[..., 2] * dst[..., 2] - q[..., 3] * dst[..., 1],
                    q[..., 0] * dst[..., 1] + q[..., 3] * dst[..., 0] - q[..., 1] * dst[..., 2],
                    q[..., 0] * dst[..., 2] + q[..., 1] * dst[..., 1] - q[..., 2] * dst[..., 0],
                ],
                -1,
            )
            scale = with_translation(scale, scale[..., :3, 3] - dst)
            w = np.where(nonzero, weight, 0.0)
            if dq_quat is None:
                dq_quat, dq_trans, dq_scale = (
                    w[..., None] * q,
                    w[..., None] * trans,
                    w[..., None, None] * scale,
                )
            else:
                flipped = dot(q, dq_quat).real < 0
                wq = np.where(flipped, -w, w)
                dq_quat = dq_quat + wq[..., None] * q
                dq_trans = dq_trans + wq[..., None] * trans
                dq_scale = dq_scale + w[..., None, None] * scale
            dq_scale_weight = dq_scale_weight + w
        else:
            sum_mat = sum_mat + mat * np.where(nonzero, weight, 0.0)[..., None, None]
        total = total + weight
    total = np.asarray(total)
    if not np.any(total.real > 0):
        return cob
    safe = np.where(total.real > 0, total, 1.0)
    if preserve:
        quat = dq_quat / safe[..., None]
        trans = dq_trans / safe[..., None]
        add = total - dq_scale_weight
        scale = dq_scale + add[..., None, None] * np.eye(4)
        scale = scale / safe[..., None, None]
        length = np.sqrt(dot(quat, quat))
        inv = np.where(length.real != 0, 1.0 / np.where(length.real != 0, length, 1.0), 0.0)
        q0 = quat * inv[..., None]
        t = trans
        R = np.zeros((*q0.shape[:-1], 4, 4), dtype=q0.dtype)
        R[..., :3, :3] = quaternion_to_matrix(q0)
        R[..., 0, 3] = (
            2.0
            * (
                -t[..., 0] * q0[..., 1]
                + t[..., 1] * q0[..., 0]
                - t[..., 2] * q0[..., 3]
                + t[..., 3] * q0[..., 2]
            )
            * inv
        )
        R[..., 1, 3] = (
            2.0
            * (
                -t[..., 0] * q0[..., 2]
                + t[..., 1] * q0[..., 3]
                + t[..., 2] * q0[..., 0]
                - t[..., 3] * q0[..., 1]
            )
            * inv
        )
        R[..., 2, 3] = (
            2.0
            * (
                -t[..., 0] * q0[..., 3]
                - t[..., 1] * q0[..., 2]
                + t[..., 2] * q0[..., 1]
                + t[..., 3] * q0[..., 0]
            )
            * inv
        )
        R[..., 3, 3] = 1.0
        sum_mat = R @ scale
    else:
        sum_mat = sum_mat / safe[..., None, None]
    return np.where((total.real > 0)[..., None, None], sum_mat @ cob, cob)


_EVALUATE = {
    "COPY_LOCATION": _copy_location,
    "COPY_ROTATION": _copy_rotation,
    "COPY_SCALE": _copy_scale,
    "COPY_TRANSFORMS": _copy_transforms,
    "STRETCH_TO": _stretch_to,
    "DAMPED_TRACK": _damped_track,
    "TRACK_TO": _track_to,
    "LOCKED_TRACK": _locked_track,
    "LIMIT_ROTATION": _limit_rotation,
    "LIMIT_LOCATION": _limit_location,
    "LIMIT_SCALE": _limit_scale,
    "ARMATURE": _armature,
    "CHILD_OF": _child_of,
}


# ----------------------------------------------------------------------------------------------------
# Targets and the solve loop, stacked.


def _at_head_tail(slot: Slot, pose):
    """The target bones' pose matrices moved ``head_tail`` along them (``constraint_target_to_mat4``)."""
    if slot.head_tail is None:
        return pose
    shift = (slot.head_tail * slot.length)[..., None] * pose[..., :3, 1]
    return with_translation(pose, pose[..., :3, 3] + shift)


def _target_in_space(cs: ConstraintStack, slot: Slot, pose, parent_pose, world: World, custom, cache=None):
    """(g, K, 4, 4) a slot's target matrix in the constraint's target space (stack layout)."""
    space = cs.target_space
    if slot.kind == "object":
        if space == "CUSTOM":
            return matmul(inverse_affine(custom), slot.matrix)
        return slot.matrix
    T = _at_head_tail(slot, pose)
    if space == "POSE":
        return T
    if space == "WORLD":
        return T if world.identity else matmul(world.matrix, T)
    if space == "LOCAL_WITH_PARENT":
        return matmul(slot.rest_inverse, T)
    if space == "CUSTOM":
        W = T if world.identity else matmul(world.matrix, T)
        return matmul(inverse_affine(custom), W)
    parenting = cache.get(slot.names) if cache is not None else None
    if parenting is None:
        parenting = Parenting(slot.stack, parent_pose)
        if cache is not None:
            cache[slot.names] = parenting
    M = parenting.to_local(T)
    if space == "LOCAL_OWNER_ORIENT":
        M = matmul(matmul(slot.diff[0], M), slot.diff[1])
    return M


def _replace_start(constraint_stacks) -> int:
    """Index of the last constraint stack that replaces the owner's transform (0 if none)."""
    start = 0
    for i, cs in enumerate(constraint_stacks):
        if cs.replaces:
            start = i
    return start


def parent_needed(bone_stack: BoneStack, constraint_stacks: Sequence[ConstraintStack]) -> bool:
    """Whether :func:`stack_pose_bones` reads the parents' poses: not for roots, nor for unconnected
    bones whose transform a constraint replaces when no later constraint works in their local space."""
    if bone_stack.root:
        return False
    start = _replace_start(constraint_stacks)
    if not constraint_stacks or not constraint_stacks[start].replaces or bone_stack.connect:
        return True
    return any(cs.owner_space in _LOCAL_SPACES and not cs.off for cs in constraint_stacks[start:])


def _blend(old, new, influence, world: World):
    """``interp_m4_m4m4`` of the world matrices before and after a constraint, in pose space."""
    if world.identity:
        return interpolate(old, new, influence, stacked=True)
    blended = interpolate(matmul(world.matrix, old), matmul(world.matrix, new), influence, stacked=True)
    return matmul(world.inverse, blended)


def _solve_one(cs: ConstraintStack, cob, parenting: Parenting, poses, parent_poses, world: World, cache=None):
    """The owner's pose matrix (g, K, 4, 4) after one constraint stack (``BKE_constraints_solve``'s loop
    body, in pose space)."""
    if cs.off:
        return cob
    nslots = len(cs.slots)
    target_poses = list(poses[:nslots])
    ctx = _Context(parenting.stack, world, cs.order, target_poses)
    evaluate = _EVALUATE[cs.type]
    if cs.in_pose_space(world):
        tars = []
        for slot, pose in zip(cs.slots, target_poses, strict=True):
            if slot.kind == "object":
                tars.append(slot.matrix if world.identity else matmul(world.inverse, slot.matrix))
            else:
                tars.append(_at_head_tail(slot, pose))
        new = evaluate(cs, cob, tars, ctx)
        if cs.type == "CHILD_OF" and cs.owner_space == "POSE" and not world.identity:
            new = matmul(world.inverse, new)  # CONSTRAINT_SPACEONCE: the result is taken as a world matrix
    else:
        custom = None
        if cs.custom is not None:
            if cs.custom.kind == "bone":
                space = poses[nslots]
                custom = space if world.identity else matmul(world.matrix, space)
            else:
                custom = cs.custom.matrix
        spaces = Spaces(parenting, world, None, custom)
        M = spaces.convert(cob, "POSE", cs.owner_space)
        tars = [
            _target_in_space(cs, slot, pose, parent, world, custom, cache)
            for slot, pose, parent in zip(cs.slots, target_poses, parent_poses[:nslots], strict=True)
        ]
        new = evaluate(cs, M, tars, ctx)
        if cs.type == "CHILD_OF":  # CONSTRAINT_SPACEONCE: the result is taken as a world matrix
            new = new if world.identity else matmul(world.inverse, new)
        else:
            new = spaces.convert(new, cs.owner_space, "POSE")
    if not cs.full:
        new = _blend(cob, new, cs.influence, world)
    return new


def _pose_stack(bone_stack, P, L, constraint_stacks, poses, parent_poses, world):
    """:func:`stack_pose_bones` in the stack layout. Constraints before the last one that replaces the
    whole transform are skipped, and so is the parenting then, but for the heads of connected bones."""
    parenting = Parenting(bone_stack, P)
    connect = bone_stack.connect
    if not constraint_stacks:
        return parenting.to_pose(L, connect=connect)
    start = _replace_start(constraint_stacks)
    if constraint_stacks[start].replaces:
        cob = None
        head = parenting.head() if connect else None
    else:
        cob = parenting.to_pose(L, connect=connect)
        head = cob[..., :3, 3] if connect else None
    cache = {}
    for cs, p, pp in zip(constraint_stacks[start:], poses[start:], parent_poses[start:], strict=True):
        cob = _solve_one(cs, cob, parenting, p, pp, world, cache)
    if head is not None:
        cob = with_translation(cob, head)
    return cob


def _array(a):
    return a if a is None or type(a) is np.ndarray else np.asarray(a)


def stack_pose_bones(
    bone_stack: BoneStack,
    parent_poses,
    locals,
    constraint_stacks: Sequence[ConstraintStack] = (),
    target_poses: Sequence[Sequence] = (),
    target_parent_poses: Sequence[Sequence] | None = None,
    world=None,
    shared: bool | None = None,
) -> np.ndarray:
    """(..., g, 4, 4) ``BKE_pose_where_is_bone`` for a stack of ``g`` bones: their pose matrices from
    their local channel matrices, through their parents and their constraints.

    Parameters
    ----------
    bone_stack : BoneStack
        The bones (one :func:`solver.rig.bones.bone_key`).
    parent_poses : (..., g, 4, 4) array_like or None
        The parents' (final) pose matrices; None for root bones, or when :func:`parent_needed` says they
        are not read.
    locals : (..., g, 4, 4) array_like or None
        The channel matrices (:func:`solver.rig.bones.channel_matrix`), or None for identity channels; their
        translations are ignored for connected bones, as Blender does.
    constraint_stacks : sequence of ConstraintStack
        The bones' constraints, position by position (each stack holds the ``g`` constraints at one
        position of the bones' constraint stacks).
    target_poses : sequence of sequences of (..., g, 4, 4) array_like
        Per constraint stack, per entry of its :attr:`ConstraintStack.inputs`: the pose matrices of those
        bones (None for object targets).
    target_parent_poses : sequence of sequences, optional
        Likewise for :attr:`ConstraintStack.parent_inputs` (None where not needed).
    world : (4, 4) array_like or solver.rig.bones.World, optional
        The armature object's ``matrix_world`` (default identity); pass a :class:`solver.rig.bones.World`
        to precompute it once.
    shared : bool, optional
        Complex inputs are complex-step directions that share their values (real parts) across the
        leading dimensions, which makes products of varying matrices cheap; default: checked.

    Leading dimensions ``...`` (complex-step directions) broadcast; constants may be ``(g, 4, 4)``.
    Arrays whose memory is stack-major (``np.moveaxis(a, 0, -3)`` of a ``(g, ..., 4, 4)`` array) are used
    without copies, and the result is such a view; it may share memory with the inputs.
    """
    if world.__class__ is not World:
        world = World.of(_EYE4 if world is None else world)
    g = bone_stack.size
    n = len(constraint_stacks)
    if len(target_poses) != n:
        if target_poses or any(cs.inputs for cs in constraint_stacks):
            raise SolverError("stack_pose_bones needs the target poses of every constraint stack")
        target_poses = ((),) * n
    if target_parent_poses is None:
        target_parent_poses = [(None,) * len(cs.inputs) for cs in constraint_stacks]
    parent_poses, locals = _array(parent_poses), _array(locals)
    target_poses = [[_array(a) for a in tp] for tp in target_poses]
    target_parent_poses = [[_array(a) for a in tp] for tp in target_parent_poses]
    lead = None
    for group in ((parent_poses, locals), *target_poses, *target_parent_poses):
        for a in group:
            if a is None:
                continue
            shape = a.shape
            if shape[-3:] != (g, 4, 4):
                raise SolverError(
                    f"stack of bones {', '.join(bone_stack.names[:3])}: matrices must be (..., {g}, 4, 4), "
                    f"got {shape}"
                )
            own = shape[:-3]
            if lead is None or lead == ():
                lead = own
            elif own != lead and own != ():
                lead = np.broadcast_shapes(lead, own)
    lead = () if lead is None else lead
    P = None if parent_poses is None else to_stack(parent_poses, lead)
    L = None if locals is None else to_stack(locals, lead)
    poses = [[None if a is None else to_stack(a, lead) for a in tp] for tp in target_poses]
    parents = [[None if a is None else to_stack(a, lead) for a in tp] for tp in target_parent_poses]
    if shared is None:
        shared = all(
            a is None or a.dtype != np.complex128 or a.shape[1] == 1 or _shared(a)
            for a in (P, L, *(x for p in poses for x in p), *(x for p in parents for x in p))
        )
    with SharedValues(shared):
        out = _pose_stack(bone_stack, P, L, constraint_stacks, poses, parents, world)
    return from_stack(out, lead)


# ----------------------------------------------------------------------------------------------------
# One bone (a stack of one).


def _target_bones(targets: Mapping[str, TargetBone]) -> dict[str, Bone]:
    bones = {}
    for name, tb in targets.items():
        bones[name] = tb.bone
        if tb.parent is not None:
            bones.setdefault(tb.parent.name, tb.parent)
    return bones


def _single_inputs(cs: ConstraintStack, targets: Mapping[str, TargetBone], con: Constraint):
    poses, parents = [], []
    for names, parent_names in zip(cs.inputs, cs.parent_inputs, strict=True):
        if names is None:
            poses.append(None)
            parents.append(None)
            continue
        tb = _target_bone(targets, names[0], con)
        poses.append(np.asarray(tb.pose)[..., None, :, :])
        parents.append(None if parent_names is None else np.asarray(tb.parent_pose)[..., None, :, :])
    return poses, parents


def _target_bone(targets: Mapping[str, TargetBone], name: str, con: Constraint) -> TargetBone:
    try:
        return targets[name]
    except KeyError:
        raise SolverError(f"constraint {con.name!r} targets bone {name!r}, which was not given") from None


def _single_stacks(bone: Bone, constraints, targets: Mapping[str, TargetBone]):
    bones = _target_bones(targets)
    for con in constraints:
        for name in [t.subtarget for t in con.targets if t.subtarget] + (
            [con.space_subtarget] if con.space_subtarget else []
        ):
            if con.unsupported() is None:
                _target_bone(targets, name, con)
    stacks = [ConstraintStack.of([c], [bone], bones) for c in constraints]
    inputs = [_single_inputs(cs, targets, c) for cs, c in zip(stacks, constraints, strict=True)]
    return stacks, [p for p, _ in inputs], [q for _, q in inputs]


def target_matrix(
    con: Constraint, target: Target, owner: Bone, targets: Mapping[str, TargetBone], world, custom
):
    """(..., 4, 4) ``constraint_target_to_mat4``: a target's matrix in the constraint's target space.

    A bone target is taken at ``head_tail`` along the bone (``pose_head`` to ``pose_tail``, orientation
    of its pose matrix), put in world space by the armature's ``world`` matrix, then converted to the
    target space as the target bone's space (``LOCAL_OWNER_ORIENT`` uses the owner's rest orientation).
    The target bone's poses in ``targets`` (:class:`TargetBone`) and ``custom``, the ``CUSTOM`` space's world
    matrix (..., 4, 4) or None, give the leading dimensions ``...`` (broadcast).
    """
    world = World.of(world)
    single = Constraint(
        con.type,
        con.name,
        1.0,
        con.owner_space,
        con.target_space,
        (target,),
        con.settings,
        con.space_subtarget,
        con.space_matrix,
    )
    cs = ConstraintStack.of([single], [owner], _target_bones(targets))
    slot = cs.slots[0]
    arrays = [custom]
    if slot.kind == "bone":
        tb = _target_bone(targets, target.subtarget, con)
        arrays += [tb.pose, tb.parent_pose if slot.parent_names is not None else None]
    present = [np.asarray(a) for a in arrays if a is not None]
    lead = np.broadcast_shapes(*(a.shape[:-2] for a in present)) if present else ()
    C, *rest = [None if a is None else to_stack(np.asarray(a)[..., None, :, :], lead) for a in arrays]
    pose, parent = rest if rest else (None, None)
    return from_stack(_target_in_space(cs, slot, pose, parent, world, C), lead)[..., 0, :, :]


def solve(bone: Bone, parent: Bone | None, parent_pose, pose, constraints, targets, world) -> np.ndarray:
    """(..., 4, 4) ``BKE_constraints_solve``: a pose matrix (..., 4, 4) after the constraints.

    Parameters are those of :func:`pose_bone`, with ``pose`` (..., 4, 4) the bone's pose matrix before
    constraints in place of ``local``; ``parent_pose`` (..., 4, 4) (None for a root bone) and the targets'
    poses broadcast against it.
    """
    stack = BoneStack.of([bone], [parent])
    world = World.of(world)
    stacks, poses, parents = _single_stacks(bone, constraints, targets)
    P = None if parent is None else np.asarray(parent_pose)[..., None, :, :]
    M = np.asarray(pose)[..., None, :, :]
    arrays = [P, M, *(x for p in poses for x in p), *(x for p in parents for x in p)]
    lead = np.broadcast_shapes(*(a.shape[:-3] for a in arrays if a is not None))
    parenting = Parenting(stack, to_stack(P, lead))
    cob = to_stack(M, lead)
    for cs, p, pp in zip(stacks, poses, parents, strict=True):
        p = [to_stack(a, lead) for a in p]
        pp = [to_stack(a, lead) for a in pp]
        cob = _solve_one(cs, cob, parenting, p, pp, world)
    return from_stack(cob, lead)[..., 0, :, :]


def pose_bone(
    bone: Bone,
    parent: Bone | None,
    parent_pose,
    local,
    constraints,
    targets: Mapping[str, TargetBone],
    world,
) -> np.ndarray:
    """(..., 4, 4) ``BKE_pose_where_is_bone``: a bone's pose matrix from its local channel matrix.

    Parameters
    ----------
    bone : Bone
    parent : Bone or None
        The parent's rest data (None for a root bone).
    parent_pose : (..., 4, 4) array_like or None
        The parent's (final) pose matrix.
    local : (..., 4, 4) array_like
        The channel matrix (:func:`solver.rig.bones.channel_matrix`); its translation is ignored for a
        connected bone, as Blender does.
    constraints : sequence of Constraint
        The bone's enabled constraints, in stack order.
    targets : Mapping[str, TargetBone]
        Every bone the constraints target (and ``CUSTOM`` space bones), posed already.
    world : (4, 4) array_like
        The armature object's ``matrix_world``.
    """
    stack = BoneStack.of([bone], [parent])
    stacks, poses, parents = _single_stacks(bone, constraints, targets)
    P = None if parent is None else np.asarray(parent_pose)[..., None, :, :]
    out = stack_pose_bones(stack, P, np.asarray(local)[..., None, :, :], stacks, poses, parents, world)
    return np.asarray(out)[..., 0, :, :]
