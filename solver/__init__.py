"""Rigs, skinning, contact IK and procedural manipulators: the pose that makes a hand meet its contacts.

* :class:`Rig` — Blender-exact armatures: bone rest matrices, Euler-angle DOFs, limits, forward kinematics.
* :class:`SkinnedMesh` — Blender's linear blend skinning with analytic derivatives.
* :class:`Armature` and :class:`ControlRig` — production rigs (Rigify) posed through their controls:
  constraints, drivers and B-Bones as Blender evaluates them (:mod:`solver.rig`, what Blender does to an
  armature), with exact derivatives.
* :class:`ContactIK` — Eq. 2 of Contact Edit (plus the markers, table and keyed-pose terms of the
  retargeting paper), solved with NLopt; :class:`Weights`, :class:`SolveResult`.
* :mod:`solver.hands` and :mod:`solver.objects` — procedural rigged hands and closed test objects;
  :func:`in_palm`, :func:`placement` and :func:`palm_centre` put an object where a hand grasps it.
* :mod:`solver.rotations` — rotations as Blender's ``mathutils`` gives them (Euler orders, quaternions).
* :func:`flex_to_contact` and :func:`grasp` — the 1988 bisection grasp, an initializer for ContactIK.
"""

from . import hands, objects, rotations
from .errors import SolverError
from .grasp import GraspResult, flex_to_contact, grasp, in_palm, palm_centre, placement
from .hands import Hand
from .ik import KEEP_OUT_WEIGHT, TOUCH_DISTANCE, ContactIK, Markers, Progress, SolveResult, Weights
from .rig import Armature, ControlRig, Kinematics, Plan, Rig, SkinnedMesh, normalize_vertex_groups
from .sdf import Box, HalfSpace, MeshSDF

__all__ = [
    "KEEP_OUT_WEIGHT",
    "TOUCH_DISTANCE",
    "Armature",
    "Box",
    "ContactIK",
    "ControlRig",
    "GraspResult",
    "HalfSpace",
    "Hand",
    "Kinematics",
    "Markers",
    "MeshSDF",
    "Plan",
    "Progress",
    "Rig",
    "SkinnedMesh",
    "SolveResult",
    "SolverError",
    "Weights",
    "flex_to_contact",
    "grasp",
    "hands",
    "in_palm",
    "normalize_vertex_groups",
    "objects",
    "palm_centre",
    "placement",
    "rotations",
]
