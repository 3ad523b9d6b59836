"""Blender's bone constraints, exactly: ``BKE_pose_where_is_bone`` in numpy, for one bone or a stack.

:func:`pose_bone` ports ``BKE_pose_where_is_bone`` (armature.cc): the local channel matrix through the
parent (:mod:`..parenting`), then ``BKE_constraints_solve`` (constraint.cc): for each constraint the
owner's world matrix is converted into the owner space, the targets' matrices
(``constraint_target_to_mat4``, with ``head_tail``) into the target space (:mod:`..spaces`), the type's
``*_evaluate`` runs, the result goes back to world space (not after Child Of: ``CONSTRAINT_SPACEONCE``)
and is blended with the matrix before the constraint by ``interp_m4_m4m4`` (:mod:`..interpolation`) when
the influence is below 1. Connected bones keep their head ("prevent constraints breaking a chain").

:func:`stack_pose_bones` does the same for ``g`` bones at once: bones whose discrete settings agree
(:func:`~solver.rig.bones.bone_key`, and :func:`constraint_key` for each constraint of their stacks) are
posed by one :class:`~solver.rig.bones.BoneStack` and one :class:`ConstraintStack` per constraint, the
continuous settings (influence, ``head_tail``, rest lengths, inverse matrices, limits ...) being arrays
over the stack. It works in pose space and skips what cannot change the result: constraints in world
space whose type reads the same in pose space under the armature's world matrix (Copy Transforms with
Replace, Copy Location and Copy Scale with default options, Stretch To, Damped Track ...), the parent and
channels of a bone whose transform a constraint replaces, and world matrices that are the identity.
:func:`pose_bone` is the stack of one bone.

Settings use Blender's RNA property names (``mix_mode``, ``use_offset``, ``head_tail`` ...); what is not
modelled exactly is named by :meth:`Constraint.unsupported`, and :func:`pose_bone` refuses it.

The modules: :mod:`.model` (the settings as data), :mod:`.constraint_stack` (many constraints as arrays),
one module per family of types (:mod:`.copying`, :mod:`.tracking`, :mod:`.limits`, :mod:`.child_of`,
:mod:`.armature`) and :mod:`.evaluate` (which function evaluates which type), :mod:`.solve` (the stacked
loop) and :mod:`.single` (one bone). Everything is batched over leading dimensions and analytic for
complex-step differentiation (see :mod:`solver.rig.analytic`).
"""

from .armature import distfactor_to_bone
from .constraint_stack import CONTINUOUS, ConstraintStack, Slot, constraint_key
from .model import DEFAULTS, MODELLED, TARGETLESS, TRACK_AXES, Constraint, Target, TargetBone
from .single import pose_bone, solve, target_matrix
from .solve import parent_needed, stack_pose_bones
from .tracking import damped_track

__all__ = [
    "CONTINUOUS",
    "DEFAULTS",
    "MODELLED",
    "TARGETLESS",
    "TRACK_AXES",
    "Constraint",
    "ConstraintStack",
    "Slot",
    "Target",
    "TargetBone",
    "constraint_key",
    "damped_track",
    "distfactor_to_bone",
    "parent_needed",
    "pose_bone",
    "solve",
    "stack_pose_bones",
    "target_matrix",
]
