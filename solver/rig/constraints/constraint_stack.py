"""Constraints of many bones evaluated at once: their discrete settings as a key (:func:`constraint_key`),
their continuous settings as arrays over the stack (:class:`ConstraintStack`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ...errors import SolverError
from ..bones import Bone, BoneStack, bone_key
from ..math_matrix import mat4_to_size
from ..math_rotation import mat4_to_eulO
from ..spaces import World, owner_orientation
from ..stack import constant
from .model import DEFAULTS, Constraint, TargetBone

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
LOCAL_SPACES = ("LOCAL", "LOCAL_OWNER_ORIENT")
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
        if constraint.target_space in LOCAL_SPACES:
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
        ``LOCAL_OWNER_ORIENT``'s change of frame (:func:`solver.rig.spaces.owner_orientation`).
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

    Build it with :meth:`of`. Its :attr:`inputs` name the bones whose poses :func:`~.solve.stack_pose_bones`
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
        self.influence = constant([c.influence for c in constraints])
        self.full = bool(self.off or self.key[3])
        if self.off:
            return self
        t = first.type
        for k in DEFAULTS[t]:
            if k in CONTINUOUS.get(t, ()):
                self.values[k] = constant([c.get(k) for c in constraints])
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
            custom.matrix = constant(matrices)
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
            slot.matrix = constant([t.matrix for t in column])
            slot.euler_order = first.euler_order
            slot.weight = constant([t.weight for t in column])
            return slot
        slot = Slot("bone")
        slot.names = tuple(t.subtarget for t in column)
        bones = [_bone_of(targets, n, what) for n in slot.names]
        slot.euler_order = bones[0].euler_order
        slot.length = constant([b.length for b in bones])
        if first.head_tail >= 1e-6:
            slot.head_tail = constant([t.head_tail for t in column])
        space = self.target_space
        if space in LOCAL_SPACES:
            parents = [_bone_of(targets, b.parent, what) if b.parent else None for b in bones]
            slot.stack = BoneStack.of(bones, parents)
            if not slot.stack.root:
                slot.parent_names = tuple(b.parent for b in bones)
            if space == "LOCAL_OWNER_ORIENT":
                rests = [b.matrix_local for b in bones]
                slot.diff = owner_orientation(rests, [o.matrix_local for o in owners])
        if space == "LOCAL_WITH_PARENT" or self.type == "ARMATURE":
            slot.rest = constant([b.matrix_local for b in bones])
            slot.rest_inverse = constant([np.linalg.inv(b.matrix_local) for b in bones])
        if self.type == "ARMATURE":
            slot.weight = constant([t.weight for t in column])
            slot.positive = first.weight > 0
            slot.envelope = bool(self.settings["use_bone_envelopes"] or bones[0].use_envelope_multiply)
            slot.envelope_data = (
                constant([b.head_local for b in bones]),
                constant([b.tail_local for b in bones]),
                constant([b.head_radius for b in bones]),
                constant([b.tail_radius for b in bones]),
                constant([b.envelope_distance for b in bones]),
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
            v["_inverse_euler"] = mat4_to_eulO(inverse, self.order)
            v["_inverse_size"] = mat4_to_size(inverse)

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
