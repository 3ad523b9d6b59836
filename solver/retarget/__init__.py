"""Retargeting contact-rich hand-object motions between different hands (Kinematic Motion Retargeting,
Lakshmipathy et al. 2025): motions, dense contact pairing, bulk contact transfer, per-frame contact IK,
refinement, B-spline fitting, metrics and the §4.6 baselines.

```python
from solver.hands import make_hand
from solver.retarget import Motion, HandSpec, default_annotation, retarget, synthetic
motion = synthetic.generate("mug")                       # or Motion.load("capture.npz"), load_grab(...)
annotation = default_annotation(make_hand("human"), make_hand("witch"))
result = retarget(motion, HandSpec("witch"), annotation)  # frames in parallel processes
result.theta, result.contact_distance, result.motion.save("witch.npz")
```
"""

from . import synthetic
from .annotate import default_annotation, make_next_procedural_topology, procedural_kind
from .annotations import AnnotationError, HandPairAnnotation
from .detection import with_contacts
from .drawn import annotation_from_patches
from .frames import FrameResult, FrameTask, HandSpec, RetargetWeights, estimate, solve_frame
from .grab import GrabError, load_grab, save_grab
from .interchange import (
    ContactSequence,
    InterchangeError,
    KeyframeMotion,
    load_markers,
    pair_markers,
    save_kmexp,
    save_markers,
)
from .job import ChildRun, JobOutcome, RetargetJob, Stopped, run_job
from .motion import Contacts, Motion, MotionError
from .pairing import pair_motion
from .pipeline import Retarget, RetargetOptions, retarget, save_result
from .propose import Proposal, Skeleton, propose_patches
from .transfer import transfer_motion

__all__ = [
    "AnnotationError",
    "ChildRun",
    "ContactSequence",
    "Contacts",
    "FrameResult",
    "FrameTask",
    "GrabError",
    "HandPairAnnotation",
    "HandSpec",
    "InterchangeError",
    "JobOutcome",
    "KeyframeMotion",
    "Motion",
    "MotionError",
    "Proposal",
    "Retarget",
    "RetargetJob",
    "RetargetOptions",
    "RetargetWeights",
    "Skeleton",
    "Stopped",
    "annotation_from_patches",
    "default_annotation",
    "estimate",
    "load_grab",
    "load_markers",
    "make_next_procedural_topology",
    "pair_markers",
    "pair_motion",
    "procedural_kind",
    "propose_patches",
    "retarget",
    "run_job",
    "save_grab",
    "save_kmexp",
    "save_markers",
    "save_result",
    "solve_frame",
    "synthetic",
    "transfer_motion",
    "with_contacts",
]
