"""The contact-free baselines of §4.6 (Kinematic Motion Retargeting) and the comparison of Table 1.

§4.6 compares the method against two retargeting objectives from tele-operation, each "augmented with
information about the known full source trajectory": both get the **ground-truth root** (here: the root
the caller passes, e.g. our own root pass, :func:`.frames.estimate`'s root results, since a retarget to
another hand has no ground truth for its root), **independent per-frame solves** (§3.4.2: every frame
starts from its own root and the rest pose of the fingers, no frame seeds another) and the **same
retroactive smoothing** (§3.4.3: :func:`resolver` turns a baseline's task list into the ``resolve``
callback of :func:`.refine.refine_trajectory`, keeping the given root).

* :mod:`.keypoints` — **fingertip keypoint tracking** (Qin et al. 2022; Eq. 3 with λc = 0):
  :func:`keypoint_tasks`.
* :mod:`.keyvectors` — **relative keyvectors** (DexPilot, Handa et al. 2019, Eq. 1-3): its cost, its
  switching rule and its solve, :func:`keyvector_tasks`.
* :mod:`.table` — **Table 1** (:func:`comparison_table`): every method's poses measured alike.
* :mod:`.inputs` — what both baselines take from our method's tasks (fingertip markers, given roots);
  :mod:`.solving` — the tasks of either (and ours) solved through one executor.

**Tasks.** Both task lists are derived from the root-stage tasks of our method
(:func:`.frames.build_tasks`) so the baselines see exactly the same inputs: the same frames, marker
targets and table. Keypoint tasks are :class:`.frames.FrameTask`; keyvector tasks are
:class:`KeyvectorTask`, solved by the module-level :func:`solve_keyvector_frame`; :func:`solve_task`
takes either, so all run through the same executor (any ``map``: a process pool, Dask) as our frames.

**In a retarget.** ``RetargetOptions(baselines=True)`` (``contact-edit retarget --baselines``) runs both
beside our method through the same executor and compares the three methods' final curves
(:mod:`.pipeline`).
"""

from .inputs import fingertip_names
from .keypoints import keypoint_tasks
from .keyvectors import (
    KEYVECTOR_CLASSES,
    KeyvectorIK,
    KeyvectorParams,
    Keyvectors,
    KeyvectorTask,
    dexpilot_targets,
    keyvector_layout,
    keyvector_problem,
    keyvector_tasks,
    solve_keyvector_frame,
)
from .keyvectors import PALM_MARKERS as PALM_MARKERS
from .keyvectors import THUMB_TIP as THUMB_TIP
from .solving import reseeded, resolver, solve_task, solve_tasks
from .table import METHODS as METHODS
from .table import MethodSummary, Table, comparison_table, frame_distances

__all__ = [
    "KEYVECTOR_CLASSES",
    "KeyvectorIK",
    "KeyvectorParams",
    "KeyvectorTask",
    "Keyvectors",
    "MethodSummary",
    "Table",
    "comparison_table",
    "dexpilot_targets",
    "fingertip_names",
    "frame_distances",
    "keypoint_tasks",
    "keyvector_layout",
    "keyvector_problem",
    "keyvector_tasks",
    "reseeded",
    "resolver",
    "solve_keyvector_frame",
    "solve_task",
    "solve_tasks",
]
