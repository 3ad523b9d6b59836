"""Table 1 of Kinematic Motion Retargeting (§4.6): the baselines and our method measured alike.

For each method, the median and mean ± standard deviation over frames of the per-frame average contact
distance and marker distance, in centimetres (:func:`comparison_table`). Both are measured the same way
for every method, from its poses (:func:`frame_distances`): the transferred target-hand contacts posed
with the method's pose against their object contacts (the baselines do not optimize them), and the
annotation's full marker set (or a named subset) against the source markers. The contact column uses
frames with contacts only.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ...errors import SolverError
from ..frames import FrameResult, FrameTask, as_hand
from .inputs import marker_rows

#: Method names of the comparison, in the paper's row order.
METHODS = ("Keypoint", "Keyvector", "Ours")


def frame_distances(
    tasks: Sequence[FrameTask], thetas, annotation=None, markers: Sequence[str] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame average contact and marker distance (metres) of poses, measured as our method's.

    Parameters
    ----------
    tasks : sequence of FrameTask
        Our method's tasks (:func:`.frames.build_tasks`): the transferred contacts and their object
        contacts, the marker points and their source positions.
    thetas : (n, d) array_like
        One pose per task.
    annotation : HandPairAnnotation, optional
        Needed with ``markers``.
    markers : sequence of str, optional
        Measure only these markers (default: all of the tasks' markers).

    Returns
    -------
    contact : (n,) ndarray
        Mean distance of the posed contacts from their object contacts (NaN for a frame without any).
    marker : (n,) ndarray
        Mean distance of the posed marker points from their targets.
    """
    T = np.asarray(thetas, dtype=np.float64)
    if T.ndim != 2 or len(T) != len(tasks):
        raise SolverError(f"thetas must have one row per task ({len(tasks)}), got shape {T.shape}")
    rows = None
    if markers is not None:
        if annotation is None:
            raise SolverError("measuring named markers needs the annotation")
        rows, _ = marker_rows(annotation, tuple(markers))
    contact = np.full(len(tasks), np.nan)
    marker = np.full(len(tasks), np.nan)
    for i, (task, theta) in enumerate(zip(tasks, T, strict=True)):
        hand = as_hand(task.hand)
        if len(task.contact_points):
            p, _ = hand.posed_points(theta, task.contact_points)
            contact[i] = np.linalg.norm(p - task.contact_targets, axis=1).mean()
        points, targets = task.marker_points, np.asarray(task.marker_targets)
        if rows is not None:
            points, targets = points[rows], targets[rows]
        if len(points):
            q, _ = hand.posed_points(theta, points)
            marker[i] = np.linalg.norm(q - targets, axis=1).mean()
    return contact, marker


@dataclass(frozen=True)
class MethodSummary:
    """One row of Table 1: a method's per-frame average distances, summarized over frames (cm).

    Attributes
    ----------
    method : str
    marker_median, marker_mean, marker_std : float
    contact_median, contact_mean, contact_std : float
        Over frames with contacts.
    frames, contact_frames : int
    marker, contact : (n,) ndarray
        The per-frame values (cm; contact NaN without contacts).
    """

    method: str
    marker_median: float
    marker_mean: float
    marker_std: float
    contact_median: float
    contact_mean: float
    contact_std: float
    frames: int
    contact_frames: int
    marker: np.ndarray = field(repr=False, compare=False)
    contact: np.ndarray = field(repr=False, compare=False)


def _summary(method: str, contact_m: np.ndarray, marker_m: np.ndarray) -> MethodSummary:
    c = 100.0 * contact_m
    m = 100.0 * marker_m
    ok = np.isfinite(c)
    cs = c[ok]

    def stats(x):
        return (float(np.median(x)), float(np.mean(x)), float(np.std(x))) if x.size else (np.nan,) * 3

    return MethodSummary(method, *stats(m[np.isfinite(m)]), *stats(cs), len(m), int(ok.sum()), m, c)


@dataclass(frozen=True)
class Table:
    """Table 1 of the paper: marker and contact distance statistics per method (cm)."""

    rows: tuple[MethodSummary, ...]
    title: str = "Baseline distance metric comparisons (cm)"

    @classmethod
    def from_distances(cls, distances: Mapping[str, tuple[np.ndarray, np.ndarray]]) -> Table:
        """The table of methods' per-frame average distances: ``{method: (contact, marker)}``, each (n,)
        in metres (contact NaN for frames without contacts), as :func:`frame_distances` measures them.
        Rows follow the mapping's order."""
        if not distances:
            raise SolverError("no methods to compare")
        return cls(
            tuple(
                _summary(method, np.asarray(contact, np.float64), np.asarray(marker, np.float64))
                for method, (contact, marker) in distances.items()
            )
        )

    def to_dict(self) -> dict:
        """The statistics as plain numbers for JSON: ``{method: {"marker_median_cm": ..., "frames": ...}}``
        (None where a statistic has no frames, e.g. contacts in a motion without any)."""
        keys = ("marker_median", "marker_mean", "marker_std", "contact_median", "contact_mean", "contact_std")

        def number(x):
            return float(x) if np.isfinite(x) else None

        return {
            r.method: {**{f"{k}_cm": number(getattr(r, k)) for k in keys}, "frames": r.frames,
                       "contact_frames": r.contact_frames}
            for r in self.rows
        }  # fmt: skip

    def row(self, method: str) -> MethodSummary:
        for r in self.rows:
            if r.method == method:
                return r
        raise KeyError(f"no method {method!r} in the table (it has {', '.join(r.method for r in self.rows)})")

    def text(self) -> str:
        """The table as plain text, in the paper's layout (median, mean ± std; marker then contact)."""
        width = max([10, *(len(r.method) for r in self.rows)]) + 2

        def cell(med, mean, std):
            return f"{med:7.3f}  {mean:7.3f} ± {std:6.3f}"

        lines = [
            self.title,
            " " * width + f"{'Marker':^25}    {'Contact':^25}",
            " " * width + f"{'Med.':>7}  {'μ ± σ':^16}    {'Med.':>7}  {'μ ± σ':^16}",  # noqa: RUF001
        ]
        for r in self.rows:
            lines.append(
                f"{r.method:<{width}}"
                + cell(r.marker_median, r.marker_mean, r.marker_std)
                + "    "
                + cell(r.contact_median, r.contact_mean, r.contact_std)
            )
        n = self.rows[0].frames if self.rows else 0
        k = self.rows[0].contact_frames if self.rows else 0
        lines.append(f"({n} frames; contact statistics over the {k} with contacts)")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.text()


def comparison_table(
    results: Mapping[str, Sequence[FrameResult]],
    tasks: Sequence[FrameTask],
    annotation=None,
    markers: Sequence[str] | None = None,
) -> Table:
    """Table 1 for several methods' per-frame results on the same frames.

    Parameters
    ----------
    results : mapping of method name -> sequence of FrameResult
        E.g. ``{"Keypoint": ..., "Keyvector": ..., "Ours": fulls}``; each must hold every task's frame
        (any order). Rows follow the mapping's order.
    tasks : sequence of FrameTask
        Our method's tasks for these frames: what is measured (:func:`frame_distances`).
    annotation, markers
        Measure only the named markers (default: the full marker set).
    """
    if not results:
        raise SolverError("no methods to compare")
    distances = {}
    for method, res in results.items():
        by_frame = {r.frame: r for r in res}
        missing = [t.frame for t in tasks if t.frame not in by_frame]
        if missing:
            raise SolverError(f"method {method!r} has no result for frames {missing[:10]}")
        thetas = np.stack([by_frame[t.frame].theta for t in tasks])
        distances[method] = frame_distances(tasks, thetas, annotation, markers)
    return Table.from_distances(distances)
