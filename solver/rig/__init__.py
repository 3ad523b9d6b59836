"""What Blender does to an armature, in numpy, exactly: bones, constraints, B-Bones, skinning, and the rigs
a solve poses.

Modules are cut by Blender concept, each a port of Blender's own code named as Blender names it:

* Blender's math: :mod:`.math_matrix` (``math_matrix.cc``, ``math_vector.cc``), :mod:`.math_rotation`
  (``math_rotation.cc``: quaternions, axis-angle, Euler orders), :mod:`.interpolation` (``interp_m4_m4m4``),
  and :mod:`.analytic`, the complex-step differentiation every port is analytic for.
* Bones: :mod:`.bones` (rest data, channels), :mod:`.parenting` (``BoneParentTransform``), :mod:`.spaces`
  (constraint spaces, the armature's world matrix), :mod:`.stack` (many bones at once).
* :mod:`.constraints` (``constraint.cc``) and :mod:`.bbone` (B-Bones, ``armature.cc``), each a package.
* What a solve poses: :class:`Rig` (:mod:`.kinematics`, a tree of directly posed bones with Euler DOFs),
  :class:`Armature` and :class:`Plan` (:mod:`.controls`: a production rig as Blender evaluated it, and
  what to solve), :class:`ControlRig` (:mod:`.control_rig`: that rig posed through its controls), both
  :class:`RigLike` (:mod:`.protocol`); :class:`SkinnedMesh` (:mod:`.skinning`, the Armature modifier);
  :mod:`.mirror` (Paste Pose Flipped).

User-facing rotation conversions (``mathutils``' normalizing ones) are :mod:`solver.rotations`.
"""

from .bbone import BBone, BBoneHandle
from .bones import Bone
from .constraints import DEFAULTS, Constraint, Target
from .control_rig import ControlKinematics, ControlRig
from .controls import Armature, Blocker, DriverInput, Plan, PoseBone
from .dofs import clipped, into_limits
from .kinematics import Kinematics, Rig
from .mirror import PoseChannel, mirror_pose
from .protocol import PosedRig, RigLike
from .skinning import SkinnedMesh, normalize_vertex_groups

__all__ = [
    "DEFAULTS",
    "Armature",
    "BBone",
    "BBoneHandle",
    "Blocker",
    "Bone",
    "Constraint",
    "ControlKinematics",
    "ControlRig",
    "DriverInput",
    "Kinematics",
    "Plan",
    "PoseBone",
    "PoseChannel",
    "PosedRig",
    "Rig",
    "RigLike",
    "SkinnedMesh",
    "Target",
    "clipped",
    "into_limits",
    "mirror_pose",
    "normalize_vertex_groups",
]
