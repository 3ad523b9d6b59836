"""Retargeting in Blender (Kinematic Motion Retargeting, 2025): a scene's hand-object motion onto another
hand, keyed as an action on its armature, and the hands' annotations it reads.

* :mod:`.scene` — the whole retarget of a scene: :func:`prepare` (main thread), the job (plain data, in a
  child process from the window), :func:`commit`; :func:`retarget_scene` runs all three for scripts.
* :mod:`.motion` — the scene's animated hand and the object it holds as a :class:`solver.retarget.Motion`.
* :mod:`.action` — a retargeted motion written as one action with its metrics.
* :mod:`.annotation` — a hand's annotation kept in the .blend: :func:`propose` one from its armature,
  :func:`hand_pair` reads two hands' as the pair's.
* :mod:`.properties` (``scene.contact_edit_retarget``) and :mod:`.operators` (Retarget, Propose, Export).

What scripts call is exported here, e.g. ``contact_edit_addon.retarget.retarget_scene(scene, source,
held, target, first, last)`` or ``contact_edit_addon.retarget.propose(hand_obj)``.
"""

from .action import write_action
from .annotation import hand_pair, propose
from .motion import SceneReader, motion_from_scene
from .scene import commit, prepare, retarget_scene

__all__ = [
    "SceneReader",
    "commit",
    "hand_pair",
    "motion_from_scene",
    "prepare",
    "propose",
    "retarget_scene",
    "write_action",
]
