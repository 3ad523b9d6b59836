"""What both baselines take from our method's tasks (:func:`.frames.build_tasks`): the annotation's
fingertip markers and the rows of its marker points, the given ("ground-truth") root of every frame, and
the DOFs a baseline solves (all but the root's, fixed to the given root)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ...errors import SolverError
from ..frames import FrameResult, FrameTask


def fingertip_names(annotation) -> tuple[str, ...]:
    """The annotation's fingertip markers (``<finger>_tip``), in its order."""
    names = tuple(m.name for m in annotation.markers if m.name.endswith("_tip"))
    if not names:
        raise SolverError("the annotation has no fingertip markers (named '<finger>_tip')")
    return names


def marker_rows(annotation, names) -> tuple[np.ndarray, np.ndarray]:
    """Rows of the annotation's full marker point list (as in ``FrameTask.marker_points`` of
    :func:`.frames.build_tasks`) that belong to the named markers, and each row's index into ``names``."""
    pairs = annotation.marker_pairs()
    index = {n: i for i, n in enumerate(pairs.names)}
    missing = [n for n in names if n not in index]
    if missing:
        raise SolverError(f"the annotation has no markers named {', '.join(missing)}")
    which = np.full(len(pairs.names), -1)
    for i, n in enumerate(names):
        which[index[n]] = i
    owner = which[pairs.marker]
    rows = np.flatnonzero(owner >= 0)
    return rows, owner[rows]


def check_tasks(tasks: Sequence[FrameTask], annotation) -> int:
    """The marker point count every task must have (the annotation's full set)."""
    if not tasks:
        raise SolverError("no tasks: give the root-stage tasks of frames.build_tasks")
    p = len(annotation.marker_pairs().target)
    for t in tasks:
        if not isinstance(t, FrameTask):
            raise SolverError(f"expected frames.FrameTask, got {type(t).__name__}")
        if len(t.marker_points) != p:
            raise SolverError(
                f"frame {t.frame}'s task has {len(t.marker_points)} marker points but the annotation's "
                f"markers have {p}: build the tasks with this annotation (frames.build_tasks)"
            )
    return p


def given_roots(roots, tasks: Sequence) -> np.ndarray:
    """(n, 6) the given root DOFs of each task's frame, from FrameResults (any order) or an array whose
    rows follow the tasks."""
    if isinstance(roots, np.ndarray) or (len(roots) and not isinstance(roots[0], FrameResult)):
        R = np.asarray(roots, dtype=np.float64)
        if R.ndim != 2 or R.shape[0] != len(tasks) or R.shape[1] < 6:
            raise SolverError(
                f"roots must have shape ({len(tasks)}, 6 or more), one row per task; got {R.shape}"
            )
        R = R[:, :6]
    else:
        by_frame = {r.frame: r for r in roots}
        missing = [t.frame for t in tasks if t.frame not in by_frame]
        if missing:
            raise SolverError(f"no root for frames {missing[:10]}")
        R = np.stack([np.asarray(by_frame[t.frame].theta[:6], dtype=np.float64) for t in tasks])
    if not np.all(np.isfinite(R)):
        raise SolverError("the given roots are not finite")
    return R


def joint_mask(rig) -> np.ndarray:
    """(d,) the DOFs a baseline solves: every one but the root's (fixed to the given root)."""
    return rig.dof_bone != 0
