"""Fingertip keypoint tracking (Qin et al. 2022), the first baseline of §4.6 (Kinematic Motion
Retargeting): "equivalent to Equation (3) with λc = 0".

:func:`keypoint_tasks` keeps only the fingertip markers of the annotation (``<finger>_tip``, see
:func:`.annotate.hand_markers`: the target's fingertip markers track the source's fingertip markers)
and solves Eq. 3 without the contact terms (table and prior stay) through :func:`.frames.solve_frame`,
the root fixed (``FrameTask.free``). The contacts are left out of those tasks rather than weighted by
zero: their terms would be exactly zero and only cost evaluations.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from geodesics import SurfacePoints

from ..frames import FrameTask, as_hand
from .inputs import check_tasks, fingertip_names, given_roots, joint_mask, marker_rows


def keypoint_tasks(
    tasks: Sequence[FrameTask],
    annotation,
    roots,
    names: Sequence[str] | None = None,
) -> list[FrameTask]:
    """Fingertip keypoint tracking (Qin et al. 2022: Eq. 3 with λc = 0) for the frames of our tasks.

    Parameters
    ----------
    tasks : sequence of FrameTask
        Our method's root-stage tasks (:func:`.frames.build_tasks` with ``annotation``): the same frames,
        marker targets, table and weights.
    annotation : HandPairAnnotation
    roots : sequence of FrameResult, or (n, >= 6) array_like
        The given ("ground-truth") root of each frame: e.g. our root pass. Rows follow ``tasks``.
    names : sequence of str, optional
        The tracked markers (default: the fingertips, :func:`fingertip_names`).

    Returns
    -------
    list of FrameTask
        Full-stage tasks with only the tracked markers, no contacts, λc = 0, the root fixed to the given
        one (``free``), the fingers seeded at their rest pose. Solve them with :func:`.frames.solve_frame`
        (or :func:`solve_task`).
    """
    check_tasks(tasks, annotation)
    names = fingertip_names(annotation) if names is None else tuple(names)
    rows, _ = marker_rows(annotation, names)
    R = given_roots(roots, tasks)
    empty = SurfacePoints(np.empty(0, np.int64), np.empty((0, 3)))
    out = []
    for task, root in zip(tasks, R, strict=True):
        rig = as_hand(task.hand).rig
        seed = rig.rest.copy()
        seed[:6] = root
        out.append(
            replace(
                task,
                stage="full",
                seed=seed,
                contact_points=empty,
                contact_targets=np.empty((0, 3)),
                contact_normals=np.empty((0, 3)),
                marker_points=task.marker_points[rows],
                marker_targets=np.asarray(task.marker_targets)[rows],
                weights=replace(task.weights, c=0.0),
                align_root=False,
                free=joint_mask(rig),
            )
        )
    return out
