"""The retargeting benchmark: a long, densely touching synthetic motion onto the 54-DOF human hand.

:func:`run` generates the motion (not timed as a stage: it stands in for captured data), retargets it
with every stage of :func:`.pipeline.retarget` in worker processes, and reports each stage's seconds
and share; then it solves the same slice of frames (root and full passes) with one and with two worker
processes for the parallel speed-up. ``contact-edit bench retarget`` prints :func:`format_report`.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..hands import make_hand
from . import synthetic
from .annotate import default_annotation
from .frames import HandSpec
from .pipeline import RetargetOptions, retarget

#: Object and contact sample density giving about 1,500 contacts per touching frame.
OBJECT = "box"
DENSITY = 90.0
#: Frames of the slice timed with one and with two workers.
SPEEDUP_FRAMES = 100


@dataclass(frozen=True)
class Report:
    frames: int
    contacts_median: float
    generate_seconds: float
    stage_seconds: dict
    workers: int
    speedup_seconds: dict
    summary: dict


def run(
    frames: int = 1000, workers: int = 2, progress: Callable[[str, int, int], None] | None = None
) -> Report:
    """Generate, retarget and time (see the module docstring)."""
    clock = time.perf_counter()
    motion = synthetic.generate(OBJECT, frames=frames, seed=0, density=DENSITY, progress=progress)
    generate_seconds = time.perf_counter() - clock
    counts = motion.hand_contacts.count()
    human = make_hand("human")
    annotation = default_annotation(human, human)
    result = retarget(motion, HandSpec("human"), annotation, workers=workers, progress=progress)
    touching = np.flatnonzero(counts > 0)
    middle = touching[len(touching) // 2]
    sl = motion.select(np.arange(middle, min(middle + SPEEDUP_FRAMES, frames)))
    options = RetargetOptions(refine=False, intersections=False, n_control=4)
    speedup = {}
    for n in (1, 2):
        with tempfile.TemporaryDirectory() as folder:
            speedup[n] = retarget(
                sl, HandSpec("human"), annotation, options, folder=folder, workers=n
            ).seconds
    return Report(
        frames, float(np.median(counts[touching])), generate_seconds, dict(result.seconds), workers,
        {n: s["root"] + s["full"] for n, s in speedup.items()}, result.summary(),
    )  # fmt: skip


def format_report(report: Report) -> str:
    total = sum(report.stage_seconds.values())
    lines = [
        f"retarget benchmark: {report.frames} frames of a synthetic {OBJECT} manipulation, "
        f"median {report.contacts_median:.0f} contacts per touching frame, onto the 54-DOF human hand",
        f"  (motion generated in {report.generate_seconds:.1f} s, not counted)",
        f"  all stages: {total:.1f} s ({total / 60:.2f} min) with {report.workers} worker processes",
    ]
    for stage, seconds in report.stage_seconds.items():
        lines.append(f"    {stage:<9} {seconds:8.1f} s  {100 * seconds / total:5.1f}%")
    one, two = report.speedup_seconds[1], report.speedup_seconds[2]
    lines.append(
        f"  root + full passes of {SPEEDUP_FRAMES} frames: 1 worker {one:.1f} s, 2 workers {two:.1f} s, "
        f"speed-up {one / two:.2f}x"
    )
    s = report.summary
    lines.append(
        f"  median contact distance {s['median_contact_distance_mm']:.2f} mm, marker distance "
        f"{s['median_marker_distance_mm']:.2f} mm, masked samples {s['masked_samples']}"
    )
    return "\n".join(lines)
