"""What Blender does to an armature, in numpy: bones, constraints, B-Bones, skinning, the rigs a solve poses.

* :class:`Rig` and :class:`Kinematics` — a tree of directly posed bones with Euler-angle DOFs.
* :class:`Armature`, :class:`Plan` and :class:`ControlRig` — a production rig (Rigify) posed through its
  controls: what Blender evaluates between the controls and the deform bones, and what a solve poses.
* :class:`SkinnedMesh` — Blender's Armature modifier, with analytic derivatives.
"""

from .control_rig import ControlKinematics, ControlRig
from .controls import Armature, Blocker, DriverInput, Plan, PoseBone
from .kinematics import Kinematics, Rig, clipped, into_limits
from .skinning import SkinnedMesh, normalize_vertex_groups

__all__ = [
    "Armature",
    "Blocker",
    "ControlKinematics",
    "ControlRig",
    "DriverInput",
    "Kinematics",
    "Plan",
    "PoseBone",
    "Rig",
    "SkinnedMesh",
    "clipped",
    "into_limits",
    "normalize_vertex_groups",
]
