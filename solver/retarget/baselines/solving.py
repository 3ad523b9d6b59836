"""Solving the baselines' tasks: either baseline's (or our method's) through the same executor as our
frames, and solved again from new seeds for the retroactive smoothing (§3.4.3), the given root kept."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from ...errors import SolverError
from ..frames import FrameResult, FrameTask, solve_frame, solve_frames
from .keyvectors import KeyvectorTask, solve_keyvector_frame


def solve_task(task: FrameTask | KeyvectorTask) -> FrameResult:
    """Solve one task of either baseline (or of our method): the function to send to workers."""
    if isinstance(task, KeyvectorTask):
        return solve_keyvector_frame(task)
    if isinstance(task, FrameTask):
        return solve_frame(task)
    raise SolverError(f"cannot solve a {type(task).__name__}: expected a FrameTask or a KeyvectorTask")


def solve_tasks(
    tasks: Sequence[FrameTask | KeyvectorTask],
    progress: Callable[[int, int], None] | None = None,
    map: Callable | None = None,
) -> list[FrameResult]:
    """Solve tasks with any ``map`` (default: the builtin), results in the tasks' order;
    ``progress(done, total)`` as they arrive."""
    return solve_frames(tasks, progress, map, solve=solve_task)


def reseeded(task: FrameTask | KeyvectorTask, seed) -> FrameTask | KeyvectorTask:
    """The task solved again from ``seed`` (d,) (a refinement's interpolated pose), except its fixed DOFs
    (the baselines' given root), which keep the task's own values."""
    seed = np.asarray(seed, np.float64)
    free = np.ones(len(seed), bool) if task.free is None else np.asarray(task.free, bool)
    new_seed = np.where(free, seed, task.seed)
    if isinstance(task, FrameTask):
        return replace(task, seed=new_seed, align_root=False)
    return replace(task, seed=new_seed)


def resolver(
    tasks: Sequence[FrameTask | KeyvectorTask], map: Callable | None = None
) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """The ``resolve(frames (k,), seeds (k, d)) -> θ (k, d)`` callback of :func:`.refine.refine_trajectory`
    for a task list (rows of the trajectory follow ``tasks``): the given frames are solved again from the
    given seeds (:func:`reseeded`)."""
    tasks = list(tasks)

    def resolve(frames: np.ndarray, seeds: np.ndarray) -> np.ndarray:
        again = [
            reseeded(tasks[int(i)], seed)
            for i, seed in zip(np.asarray(frames, np.int64), np.asarray(seeds, np.float64), strict=True)
        ]
        return np.stack([r.theta for r in solve_tasks(again, map=map)])

    return resolve
