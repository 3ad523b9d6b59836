"""B-Bones evaluated together: bones whose discrete settings agree share a :class:`BBoneStack` (:func:`stacks`
groups a rig's B-Bones into few), which holds every constant of their rest pose as arrays over the
stack."""

from __future__ import annotations

import numpy as np

from ...errors import SolverError
from .. import analytic
from .model import BBone


class Side:
    """The handles at one end (start or end) of the bones of a stack; arrays over the stack axis."""

    def __init__(self, side: str, bbones, key):
        self.side = side
        self.kind, self.joins, self.reads_scale, self.has_parent = key
        handles = [getattr(bb, side) if side_key(bb, side) is not None else None for bb in bbones]
        self.present = np.array([h is not None for h in handles])
        self.absent = np.flatnonzero(~self.present)
        self.partial = not self.present.all()
        self.names = tuple(None if h is None else h.name for h in handles)
        self.parent_names = tuple(h.parent if h is not None and self.has_parent else None for h in handles)
        some = next(h for h in handles if h is not None)
        handles = [some if h is None else h for h in handles]  # stand-ins, masked out
        self.head_local = np.array([h.head_local for h in handles]).T[:, None]  # (3, 1, g)
        self.length = np.array([h.length for h in handles])
        if self.reads_scale:
            self.use_scale = (
                np.array([getattr(bb, f"handle_use_scale_{side}") for bb in bbones], float).T * self.present
            )[:, None]  # (3, 1, g)
            self.use_ease = np.array([getattr(bb, f"handle_use_ease_{side}") for bb in bbones], float)
            self.use_ease = self.use_ease * self.present
            # inv(rotscale) = inv(parent_offset) inv(parent_pose), or inv(matrix_local)
            self.rest_inverse = np.moveaxis(
                np.array(
                    [
                        np.linalg.inv((h.parent_offset if self.has_parent else h.matrix_local)[:3, :3])
                        for h in handles
                    ]
                ),
                0,
                -1,
            )[:, :, None]  # (3, 3, 1, g)


def side_key(bb: BBone, side: str):
    """The discrete settings of one end of a B-Bone that the curve's math branches on (None: no handle):
    (handle type, the handle is a B-Bone the curve joins, its scale is read, its parent is needed)."""
    handle = getattr(bb, side)
    if bb.segments == 1 or handle is None:
        return None
    joins = bb.start_joins() if side == "start" else bb.end_joins()
    reads = bb.reads_handle_scale(side)
    return (getattr(bb, f"handle_type_{side}"), joins, reads, reads and handle.parent is not None)


def stack_keys(bbones) -> tuple[int, object, object] | None:
    """The common (segments, start key, end key) of B-Bones that can share a stack, or None. A bone
    without a handle at one end fits a stack whose other bones have one there (it is masked out)."""
    segments = {bb.segments for bb in bbones}
    if len(segments) != 1:
        return None
    keys = []
    for side in ("start", "end"):
        found = {side_key(bb, side) for bb in bbones} - {None}
        if len(found) > 1:
            return None
        keys.append(found.pop() if found else None)
    return segments.pop(), keys[0], keys[1]


class BBoneStack:
    """B-Bones that :func:`~solver.rig.bbone.stack_deform_matrices` evaluates together.

    They have the same ``segments`` and, at each end, the same handle type, the same kind of handle (a
    B-Bone the curve joins, or not) and the same use of the handle's scale (``bbone_handle_use_scale_*``
    / ``bbone_handle_use_ease_*`` on or off, the handle having a parent or not), among the bones that
    have a handle there; a bone without a handle at an end is masked out of that end's math. Every other
    setting (rest matrices, lengths, ease, roll, curve, scale, the handles' rest data, ``mapping_mode``)
    may differ from bone to bone. Build with :meth:`of` or :func:`stacks`.

    Attributes
    ----------
    bbones : tuple of BBone
        The bones, in the order of the stack axis ``g`` of :func:`~solver.rig.bbone.stack_deform_matrices`.
    segments : int
        Their ``bbone_segments``.
    start, end : Side or None
        The handles at each end (None where no bone has one); ``sides`` those present, ``rolled`` those
        whose roll the curve reads.

    The other attributes are the rest pose's constants the stacked curve reads (:mod:`.stacked`,
    :mod:`.jacobian`, :mod:`.deform`), arrays over the stack axis last: ``length``, ``eps2`` (the squared
    handle length below which a handle points along +y), ``present``, ``partial``, ``offset``, ``sign``
    (per side), ``ease``, ``roll``, ``curve``, ``scale_in``, ``scale_out``, ``blend``, ``fractions``,
    ``scale_xz``, ``reads_scale``, ``entries`` (the pose entries the curve reads), ``unbend`` and its
    layouts ``unbend_t``, ``unbend_rows``; ``inverse_rest`` for plain bones.
    """

    def __init__(self, bbones, keys):
        self.bbones = tuple(bbones)
        self.segments, start_key, end_key = keys
        self._templates: dict = {}
        s = self.segments
        if s == 1:
            self.inverse_rest = np.array([np.linalg.inv(bb.matrix_local) for bb in self.bbones])
            self.start = self.end = None
            return
        self.start = None if start_key is None else Side("start", self.bbones, start_key)
        self.end = None if end_key is None else Side("end", self.bbones, end_key)
        self.sides = sides = [x for x in (self.start, self.end) if x is not None]
        self.length = np.array([bb.length for bb in self.bbones])
        self.eps2 = (1e-5 * self.length) ** 2
        self.partial = any(x.partial for x in sides)
        if sides:
            self.present = np.stack([x.present for x in sides])[:, None]  # (sides, 1, g)
            # Blender shortens a handle by the bone's length unless it is a joined start or a joined end
            self.offset = np.array([float(x.joins if x.side == "start" else not x.joins) for x in sides])
            self.offset = self.offset[:, None, None]
            self.sign = np.array([-1.0 if x.side == "start" else 1.0 for x in sides])[:, None, None]
        self.rolled = [x for x in sides if not (x.side == "start" and x.joins)]
        # the entries (4 r + c, top three rows) of each posed matrix the curve depends on
        every, rotation, head = np.arange(12), np.array([0, 1, 2, 4, 5, 6, 8, 9, 10]), np.array([3, 7, 11])
        self.entries = [every]
        for x in (self.start, self.end):
            if x is None:
                self.entries.append(None)
            elif x.side == "start" and x.joins:
                self.entries.append(head)
            else:
                self.entries.append(rotation if x.kind == "TANGENT" else every)
        self.entries += [rotation, rotation]
        # BKE_pchan_bbone_spline_params_get's constants, bone and pose levels combined
        ease, roll, curve, scale_in, scale_out = [], [], [], [], []
        for bb in self.bbones:
            e = [bb.bone_ease_in + bb.pose_ease_in, bb.bone_ease_out + bb.pose_ease_out]
            r = [bb.bone_roll_in + bb.pose_roll_in, bb.bone_roll_out + bb.pose_roll_out]
            if bb.use_endroll_as_inroll and bb.start is not None:
                r[0] += bb.start.bone_roll_out + bb.start.pose_roll_out
            c = np.array(
                [
                    [bb.bone_curve_in_x + bb.pose_curve_in_x, 0.0, bb.bone_curve_in_z + bb.pose_curve_in_z],
                    [
                        bb.bone_curve_out_x + bb.pose_curve_out_x,
                        0.0,
                        bb.bone_curve_out_z + bb.pose_curve_out_z,
                    ],
                ]
            )
            si, so = bb.bone_scale_in * bb.pose_scale_in, bb.bone_scale_out * bb.pose_scale_out
            if bb.use_scale_easing:
                e = [e[0] * si[1], e[1] * so[1]]
                c = c * np.array([[si[1]], [so[1]]])
            ease.append([e[0], -e[1]])
            roll.append(r)
            curve.append(c)
            scale_in.append(si)
            scale_out.append(so)
        self.ease = np.array(ease).T[:, None]  # (2, 1, g): ease in, minus ease out
        self.roll = np.array(roll).T[:, None]  # (2, 1, g)
        self.curve = np.moveaxis(np.array(curve), 0, -1)[:, :, None]  # (2, 3, 1, g) -> per side, xyz
        self.curve = self.curve.swapaxes(0, 1)  # (3, 2, 1, g)
        self.scale_in = np.array(scale_in).T[:, None]  # (3, 1, g)
        self.scale_out = np.array(scale_out).T[:, None]
        f = np.arange(s + 1) / s
        self.blend = np.stack([1 - f, f], -1)  # (a, 2): joint a takes (1 - f) of the in, f of the out
        self.reads_scale = any(x.reads_scale for x in sides)
        if not self.reads_scale:
            self.fractions = segment_fractions(self.scale_in[1], self.scale_out[1], s)  # (s - 1, 1, g)
            self.scale_xz = interpolate_joints(self.blend, self.scale_in[::2], self.scale_out[::2])
        unbend = np.array([bb.unbend for bb in self.bbones])  # (g, a, 4, 4)
        self.unbend = np.moveaxis(unbend, (2, 3, 1, 0), (0, 1, 2, 3))[:, :, :, None]  # (4, 4, a, 1, g)
        self.unbend_t = unbend.swapaxes(-1, -2).copy()  # (g, a, 4, 4), transposed
        self.unbend_rows = unbend  # (g, a, 4, 4)

    def steps(self, complex_: tuple[bool, ...], g: int) -> list:
        """Per posed-matrix argument, the imaginary parts (4, 4, m, g) giving one complex-step direction to
        each entry the curve reads of the complex arguments (``complex_``), m of them in all."""
        key = ("steps", complex_)
        steps = self._templates.get(key)
        if steps is None:
            entries = [e if c else [] for e, c in zip(self.entries, complex_, strict=True)]
            m, q, steps = sum(len(e) for e in entries), 0, []
            for e in entries:
                step = np.zeros((4, 4, m, g))
                step[np.asarray(e, int) // 4, np.asarray(e, int) % 4, q + np.arange(len(e))] = analytic.STEP
                steps.append(step)
                q += len(e)
            self._templates[key] = steps
        return steps

    def powers(self, batch, dtype) -> np.ndarray:
        """(4, a, *batch) a fresh array of 1, t, t², t³ for the joints' curve parameters t, filled at the
        ends (t = 0 and 1); the inner joints are left to fill."""
        key = (batch, dtype)
        template = self._templates.get(key)
        if template is None:
            if len(self._templates) > 16:
                self._templates.clear()
            template = np.zeros((4, self.segments + 1, *batch), dtype)
            template[0] = 1.0
            template[1:, self.segments] = 1.0
            self._templates[key] = template
        return template.copy()

    @classmethod
    def of(cls, bbones) -> BBoneStack:
        """The stack of these B-Bones, in this order.

        Raises
        ------
        SolverError
            When the list is empty, holds something else than BBone, or holds bones that cannot share
            a stack (see :class:`BBoneStack`; the message names two of them).
        """
        bbones = tuple(bbones)
        if not bbones or not all(isinstance(bb, BBone) for bb in bbones):
            raise SolverError(f"a B-Bone stack needs one or more BBone, got {bbones!r:.200}")
        keys = stack_keys(bbones)
        if keys is None:
            first = bbones[0]
            other = next((bb for bb in bbones[1:] if stack_keys((first, bb)) is None), bbones[-1])
            raise SolverError(
                f"B-Bones {first.name!r} and {other.name!r} cannot share a stack: their segments, handle "
                f"types, kinds of handle (a B-Bone or not) or uses of a handle's scale differ"
            )
        return cls(bbones, keys)

    @property
    def names(self) -> tuple[str, ...]:
        """The bones' names, along the stack axis."""
        return tuple(bb.name for bb in self.bbones)

    @property
    def handle_names(self) -> tuple[tuple[str | None, ...] | None, tuple[str | None, ...] | None]:
        """(start, end): per bone, the handle bone whose posed matrix goes in ``starts`` / ``ends`` of
        :func:`~solver.rig.bbone.stack_deform_matrices` (``None`` for a bone without one), or ``None`` for a
        side where no bone of the stack has a handle (then pass ``None``)."""
        return tuple(None if x is None else x.names for x in (self.start, self.end))  # type: ignore[return-value]

    @property
    def handle_parent_names(self) -> tuple[tuple[str | None, ...] | None, tuple[str | None, ...] | None]:
        """(start, end): per bone, the parent of the handle whose posed matrix goes in
        ``start_parents`` / ``end_parents`` (its scale is read), or ``None`` for a side that needs
        none."""
        return tuple(
            None if x is None or not x.has_parent else x.parent_names for x in (self.start, self.end)
        )  # type: ignore[return-value]

    def gather(self, pose) -> tuple:
        """``(poses, starts, ends, start_parents, end_parents)`` for
        :func:`~solver.rig.bbone.stack_deform_matrices`, each (..., g, 4, 4) (the bones' batch shapes
        broadcast) or None where the stack needs none, from ``pose``, a mapping or a callable giving a bone's
        posed matrix (..., 4, 4) by name; a bone without a handle gets its own pose in the handle's place."""
        get = pose if callable(pose) else pose.__getitem__

        def stacked(names):
            if names is None:
                return None
            mats = [
                np.asarray(get(own if n is None else n)) for n, own in zip(names, self.names, strict=True)
            ]
            shape = np.broadcast_shapes(*(m.shape for m in mats))
            return np.stack([np.broadcast_to(m, shape) for m in mats], axis=-3)

        return (
            stacked(self.names),
            *map(stacked, self.handle_names),
            *map(stacked, self.handle_parent_names),
        )

    def __len__(self) -> int:
        return len(self.bbones)

    def __repr__(self) -> str:
        return f"BBoneStack({', '.join(self.names)}; segments={self.segments})"


def interpolate_joints(blend, start, end):
    """(a, ...) per joint ``(1 - f) start + f end`` from (n, ...) per bone values: (n, a, ...)."""
    return start[:, None] * blend[:, 0, None, None] + end[:, None] * blend[:, 1, None, None]


def segment_fractions(scale_in_y, scale_out_y, segs: int):
    """(segs - 1, ...) where ``equalize_cubic_bezier`` puts the inner joints, as fractions of the curve's
    length, from the y scales in and out (``BKE_pchan_bbone_spline_compute``)."""
    log_in = analytic.log(np.where(scale_in_y.real < 1e-4, 1e-4, scale_in_y))
    log_out = analytic.log(np.where(scale_out_y.real < 1e-4, 1e-4, scale_out_y))
    fac = (np.arange(segs) / (segs - 1)).reshape(segs, *(1,) * log_in.ndim)
    cumulative = np.cumsum(analytic.exp(fac * log_out + (1 - fac) * log_in), axis=0)
    return cumulative[: segs - 1] / cumulative[-1]


def stacks(bbones) -> list[BBoneStack]:
    """Group B-Bones into few :class:`BBoneStack`: each bone joins the first stack it fits, in order.
    Plain bones (``segments == 1``) are grouped too."""
    groups: list[list[BBone]] = []
    for bb in bbones:
        if not isinstance(bb, BBone):
            raise SolverError(f"stacks takes BBone, got {type(bb).__name__}")
        for group in groups:
            if stack_keys((*group, bb)) is not None:
                group.append(bb)
                break
        else:
            groups.append([bb])
    return [BBoneStack.of(group) for group in groups]
