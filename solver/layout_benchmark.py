"""The benchmark a person's layouts drive (issue 41, item 5): does a solve from rest find the grip?

For every hand, every object of :data:`solver.layouts.OBJECTS` whose known grip has two pads or more,
and every bin of the object's turn (:data:`solver.layouts.BINS`), ``per_bin`` seeded layouts
(:func:`solver.layouts.make_layout`: pads of a grip that exists, targets slid a few millimetres, the
object carried away) are solved from the rest pose exactly as a user's script solves them::

    ContactIK(hand, layout.points, layout.positions, layout.normals, keep_out=layout.sdf,
              patches=layout.patches).solve()

with every other argument at the solve's default (the pads named, as the add-on names its patches), so
the same run measures whatever the solve does today and after it changes. Each pose is judged
(:func:`solver.layouts.judge`: every pad's median distance to the surface within 2 mm, to its patch
within 8 mm, no skin more than 1 mm inside). Then one pad that touches (a seeded choice) is turned 25°
on the surface (:func:`solver.layouts.turned`) and the layout re-solved from the solved pose,
``solve(theta0=...)``: the edit *flips* the hand when the palm turns by more than 30° or a pad that
touched no longer does (:func:`solver.layouts.judge_edit`).
Layouts where no pad touches after the first solve have nothing to turn and are not edited.

:func:`run` returns a :class:`LayoutRow` per hand and bin and one per hand for the edits;
:func:`format_table` prints them. Rows are not :class:`geodesics.benchmark.Row`, which holds one timing
beside a peer's: these are rates and counts per bin (success, flips) with the times of many solves, and
a column each lets a table before a change be read against one after it. ``progress`` gets a line per
layout. A Rigify hand (any skin of a procedural hand's mesh) joins the run through ``others``: it gets
that hand's layouts (:func:`solver.layouts.on_hand`). :data:`PER_BIN` keeps the default run to one
layout per object and bin, which a slow solve can afford; ``per_bin`` refines the rates once solves are
fast. :data:`QUICK` is the smallest run, for tests.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from . import hands
from .errors import SolverError
from .ik import ContactIK, SolveResult
from .layouts import (
    BINS,
    OBJECTS,
    TURN_LIMIT,
    EditVerdict,
    Layout,
    Verdict,
    judge,
    judge_edit,
    known_grip,
    make_layout,
    on_hand,
    turned,
)
from .rig import SkinnedMesh

#: Layouts per object and bin by default: 36 layouts over the three procedural hands (four objects, three
#: bins), each solved twice (once more for its edit).
PER_BIN = 1
#: The hands :func:`run` poses by default (the tentacle has no palm to grip with).
KINDS = ("human", "alien", "witch")
#: How far the edit turns a pad (degrees).
EDIT_DEGREES = 25.0
#: The smallest run, for tests: one hand, one object, one bin, one layout.
QUICK = {"kinds": ("alien",), "objects": ("cylinder",), "bins": BINS[:1], "per_bin": 1}


@dataclass(frozen=True)
class Edit:
    """One pad of a solved layout turned by :data:`EDIT_DEGREES` and re-solved from the solved pose."""

    pad: int
    result: SolveResult
    verdict: Verdict
    change: EditVerdict


@dataclass(frozen=True)
class Trial:
    """One layout solved from rest, judged, and (where a pad touches) edited."""

    hand: str
    layout: Layout
    result: SolveResult
    verdict: Verdict
    edit: Edit | None


@dataclass(frozen=True)
class LayoutRow:
    """One line of the table: a hand's solves in one bin of wrist turn, or its edits.

    Attributes
    ----------
    hand : str
    what : str
        The bin (``"turn 0-45°"``) or ``"edit: one pad turned 25°"``.
    layouts : int
        Solves in the row.
    success : int
        How many of them the judge passed.
    edits : int
        Edits made (of the bin's layouts; for the edit row, the same as ``layouts``).
    flips : int
        Edits that flipped the hand.
    seconds : float
        Median seconds of the row's solves.
    slowest : float
        Slowest solve, seconds.
    evaluations : float
        Median objective evaluations.
    note : str
    """

    hand: str
    what: str
    layouts: int
    success: int
    edits: int
    flips: int
    seconds: float
    slowest: float
    evaluations: float
    note: str = ""

    @property
    def rate(self) -> float:
        """Success in percent (NaN for an empty row)."""
        return 100.0 * self.success / self.layouts if self.layouts else float("nan")


#: How a layout is solved: as a user's script solves it (every argument at its default but the object), or
#: as Contact Edit solves (NLopt's SLSQP, locally from the given pose).
SOLVES = ("default", "paper")


def _solve(layout: Layout, theta0=None, solve: str = "default") -> SolveResult:
    """A solve of a layout (see :data:`SOLVES`), from rest or from θ0."""
    if solve == "paper":
        ik = ContactIK(layout.hand, layout.points, layout.positions, layout.normals, keep_out=layout.sdf,
                       algorithm="slsqp")  # fmt: skip
        return ik.solve(theta0, start="local", press=False)
    ik = ContactIK(layout.hand, layout.points, layout.positions, layout.normals, keep_out=layout.sdf,
                   patches=layout.patches)  # fmt: skip
    return ik.solve() if theta0 is None else ik.solve(theta0=theta0)


def trial(hand_label: str, layout: Layout, seed=0, solve: str = "default") -> Trial:
    """Solve ``layout`` from rest, judge it, then turn a touching pad (seeded choice) by
    :data:`EDIT_DEGREES`, re-solve from the solved pose and judge the edit.

    Parameters
    ----------
    hand_label : str
        The hand's name in the table.
    layout : Layout
    seed : int or sequence of int
        Seeds the choice of the pad to turn.
    solve : str
        One of :data:`SOLVES`.

    Returns
    -------
    Trial
    """
    hand = layout.hand
    result = _solve(layout, solve=solve)
    verdict = judge(hand, result.theta, layout)
    touching = np.flatnonzero(verdict.touching)
    edit = None
    if touching.size:
        pad = int(np.random.default_rng(seed).choice(touching))
        edited = turned(layout, pad, EDIT_DEGREES)
        again = _solve(edited, theta0=result.theta, solve=solve)
        after = judge(hand, again.theta, edited)
        edit = Edit(pad, again, after, judge_edit(hand, verdict, after, layout.palm))
    return Trial(hand_label, layout, result, verdict, edit)


def _describe(trial: Trial) -> str:
    """The progress line of one trial."""
    layout, verdict, edit, result = trial.layout, trial.verdict, trial.edit, trial.result
    outcome = "success" if verdict.success else "fail"
    line = (
        f"{trial.hand} {layout.name} turned {layout.angle:.0f}°, moved {1e3 * layout.shift:.0f} mm, "
        f"{len(layout.pads)} pads: {outcome} in {result.seconds:.2f} s ({result.status}; worst pad "
        f"{1e3 * verdict.contact.max():.1f} mm off the surface, {1e3 * verdict.reach.max():.1f} mm from its "
        f"patch; skin {1e3 * verdict.depth:.1f} mm deep)"
    )
    if edit is None:
        return line + "; no pad touches, no edit"
    outcome = "flip" if edit.change.flip else "kept"
    return line + (
        f"; {layout.pads[edit.pad]} turned {EDIT_DEGREES:.0f}°: {outcome} (palm turned "
        f"{edit.change.turn:.1f}°, {len(edit.change.dropped)} pads dropped) in {edit.result.seconds:.2f} s "
        f"({edit.result.status})"
    )


def _row(hand: str, what: str, results: list[SolveResult], success: int, edits: list[Edit], note: str):
    seconds = [r.seconds for r in results]
    return LayoutRow(
        hand=hand,
        what=what,
        layouts=len(results),
        success=success,
        edits=len(edits),
        flips=sum(e.change.flip for e in edits),
        seconds=float(np.median(seconds)) if seconds else float("nan"),
        slowest=max(seconds, default=float("nan")),
        evaluations=float(np.median([r.iterations for r in results])) if results else float("nan"),
        note=note,
    )


def rows_of(trials: Sequence[Trial], bins: Sequence[tuple[float, float]] = BINS) -> list[LayoutRow]:
    """The table's rows of ``trials``: per hand (in order of appearance) a row per bin, then its edits."""
    rows = []
    for hand in dict.fromkeys(t.hand for t in trials):
        mine = [t for t in trials if t.hand == hand]
        groups = []  # (what, solves, successes, edits, note) per row
        for lo, hi in bins:
            inside = [t for t in mine if t.layout.bin == (float(lo), float(hi))]
            pads = [len(t.layout.pads) for t in inside]
            groups.append((
                f"turn {lo:.0f}-{hi:.0f}°",
                [t.result for t in inside],
                sum(t.verdict.success for t in inside),
                [t.edit for t in inside if t.edit is not None],
                f"{min(pads)}-{max(pads)} pads" if pads else "",
            ))  # fmt: skip
        edits = [t.edit for t in mine if t.edit is not None]
        turns = [e.change.turn for e in edits]
        groups.append((
            f"edit: one pad turned {EDIT_DEGREES:.0f}°",
            [e.result for e in edits],
            sum(e.verdict.success for e in edits),
            edits,
            f"palm turned {np.median(turns):.1f}° median, {max(turns):.1f}° most" if turns else "",
        ))  # fmt: skip
        rows += [_row(hand, *group) for group in groups]
    return rows


def layouts_for(
    hand: SkinnedMesh, kind: str, objects: Sequence[str], bins, per_bin: int, seed: int
) -> tuple[list[Layout], list[str]]:
    """The seeded layouts of a hand of ``kind`` (its procedural grips; another skin of the same mesh gets
    them through :func:`solver.layouts.on_hand`), object by object, bin by bin, and the grips skipped
    for want of pads (as ``"sphere: 1 pad"``)."""
    kit = hand if isinstance(hand, hands.Hand) and hand.kind == kind else hands.make_hand(kind)
    layouts, skipped = [], []
    for o, name in enumerate(objects):
        grip = known_grip(kit, name)
        if not grip.usable:
            skipped.append(f"{name}: {len(grip.pads)} pad{'s' if len(grip.pads) != 1 else ''}")
            continue
        for b, bin in enumerate(bins):
            for i in range(per_bin):
                layout = make_layout(grip, bin, seed=[seed, o, b, i])
                layouts.append(layout if kit is hand else on_hand(layout, hand))
    return layouts, skipped


def run(
    kinds: Sequence[str] = KINDS,
    per_bin: int = PER_BIN,
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
    *,
    objects: Sequence[str] = tuple(OBJECTS),
    bins: Sequence[tuple[float, float]] = BINS,
    others: Mapping[str, tuple[SkinnedMesh, str]] | None = None,
    solve: str = "default",
) -> list[LayoutRow]:
    """Solve person-like layouts from rest for each hand and bin, edit each, and tabulate.

    Parameters
    ----------
    kinds : sequence of str
        Procedural hands (:func:`solver.hands.make_hand` kinds with fingers).
    per_bin : int
        Layouts per object and bin.
    seed : int
    progress : callable, optional
        Receives a line of text per layout (and one per hand before its grips are made).
    objects : sequence of str
        Names in :data:`solver.layouts.OBJECTS`.
    bins : sequence of (2,) tuples
        Bins of the object's turn, degrees.
    others : mapping, optional
        More hands by label: ``(skin, kind)``, a skin of the procedural ``kind``'s mesh (a Rigify rig
        skinning it), given that kind's layouts (:func:`solver.layouts.on_hand`).
    solve : str
        One of :data:`SOLVES`: the default solve, or Contact Edit's for comparison.

    Returns
    -------
    list of LayoutRow
        Per hand, a row per bin and one for the edits (:func:`rows_of`); a hand's first row notes the
        grips skipped for want of pads.
    """
    say = progress or (lambda _line: None)
    if solve not in SOLVES:
        raise SolverError(f"solve must be one of {', '.join(SOLVES)}, got {solve!r}")
    if int(per_bin) < 1:
        raise SolverError(f"per_bin must be at least 1, got {per_bin!r}")
    unknown = [k for k in kinds if k not in KINDS]
    if unknown:
        raise SolverError(f"the benchmark poses hands with fingers: {', '.join(KINDS)}; got {unknown[0]!r}")
    hands_to_run = [(kind, hands.make_hand(kind), kind) for kind in kinds]
    hands_to_run += [(label, skin, kind) for label, (skin, kind) in (others or {}).items()]
    rows = []
    for label, hand, kind in hands_to_run:
        say(f"{label}: grips and layouts")
        layouts, skipped = layouts_for(hand, kind, objects, bins, int(per_bin), seed)
        trials = []
        for n, layout in enumerate(layouts):
            trials.append(trial(label, layout, seed=[seed, n], solve=solve))
            say(_describe(trials[-1]))
        mine = rows_of(trials, bins) if trials else []
        if skipped and mine:
            note = "; ".join(x for x in (mine[0].note, f"grips skipped: {', '.join(skipped)}") if x)
            mine[0] = replace(mine[0], note=note)
        rows += mine
    return rows


#: The table's columns: title, width, and the cell of a row (cells of empty rows are "-").
COLUMNS: tuple[tuple[str, int, Callable[[LayoutRow], str]], ...] = (
    ("layouts", 7, lambda r: f"{r.layouts}"),
    ("success", 13, lambda r: f"{r.success}/{r.layouts} {r.rate:3.0f}%"),
    (f"flips >{TURN_LIMIT:.0f}°", 10, lambda r: f"{r.flips}/{r.edits}" if r.edits else "-"),
    ("median s", 9, lambda r: f"{r.seconds:.2f}"),
    ("slowest s", 9, lambda r: f"{r.slowest:.2f}"),
    ("evals", 6, lambda r: f"{r.evaluations:.0f}"),
)


def format_table(rows: Sequence[LayoutRow]) -> str:
    """A plain-text table of the rows: success and flips as counts and rates, seconds and evaluations."""
    header = [f"{'hand':10} {'what':26}"] + [f"{title:>{width}}" for title, width, _ in COLUMNS] + [" note"]
    table = [" ".join(header)]
    for r in rows:
        cells = [f"{(cell(r) if r.layouts else '-'):>{width}}" for _, width, cell in COLUMNS]
        table.append(" ".join([f"{r.hand:10} {r.what:26}", *cells, f" {r.note}"]))
    return "\n".join(table)
