"""The host's picture of the device: a parent→children table built from records (Appendix A, by the
firmware's facts).

:class:`DeviceTopology` is the mutable table; it is not thread-safe on its own (the
:class:`~tangible.reader.SerialReader` guards it with a lock) and needs no thread or clock, so recorded
replies can be replayed through it offline. :meth:`DeviceTopology.snapshot` returns an immutable
:class:`DeviceState`.

Rules (see ``PROTOCOL.md``, "The host's picture"):

* The firmware's first relayer writes its id into a record (and a splitter its port), so a record from
  ``c`` with relayer ``r`` and port ``s`` places ``c`` in slot ``s`` of ``r``; relayer 0 means ``c`` is the
  piece the host polls (slot 0 of the host). A newer claim on an occupied slot, or one that would close a
  cycle, unlinks the stale entry, which stays unplaced (detached) until it speaks again. A record that
  names its creator as its relayer (a joint's two halves in data mode 2) places nothing.
* ``c`` is *heard* when a record it created arrives or one it relayed (its id as relayer proves it was
  powered and linked).
* ``c`` is **attached** when it was heard within ``timeout`` seconds (2 s by default) and its parent is the
  host or attached: a piece silent for longer is detached with its whole subtree, and re-attached as soon
  as it (or a child through it) speaks.
* The firmware numbers nothing, so lost records cannot be told per piece: the link's counters
  (:class:`LinkStats`) say how many records were corrupt and how many replies were short or missing.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

from geodesics.arrays import readonly

from .errors import DeviceError
from .joint import joint_rotation
from .protocol import (
    NODE_JOINT_TUT_T,
    AckRecord,
    DataRecord,
    InitRecord,
    Record,
    SplitterRecord,
    splitter_rotation,
)

__all__ = ["DETACH_TIMEOUT", "ComponentState", "DeviceState", "DeviceTopology", "LinkStats"]

#: Seconds of silence after which a component and its subtree count as detached (Appendix A).
DETACH_TIMEOUT = 2.0


@dataclass(frozen=True)
class LinkStats:
    """Counters of the serial link (cumulative since the reader started).

    ``bytes`` read; ``frames`` valid records (empty ones not counted) and ``empty`` empty ones;
    ``corrupt`` damaged spots (a record failing its checks, or bytes a dropped, inserted or cut-off byte
    made unreadable) and ``skipped`` bytes not in any valid record; replies ``short`` of 216 bytes,
    ``oversize`` (longer) and ``missing`` (no reply to a poll); ``polls`` written, ``echoes`` of them
    heard back and skipped, ``commands`` sent (each counted once), ``resent`` the times one was sent again
    for want of an acknowledgement and ``unacknowledged`` those given up after the reader's attempts, with
    ``command_error`` the last in words ("" when none); ``reconnects`` successful re-openings of the port
    after it failed; ``error`` the last port error in words ("" when none). See
    :class:`tangible.protocol.ParserStats` and :class:`tangible.reader.SerialReader`.
    """

    bytes: int = 0
    frames: int = 0
    empty: int = 0
    corrupt: int = 0
    skipped: int = 0
    short: int = 0
    oversize: int = 0
    missing: int = 0
    polls: int = 0
    echoes: int = 0
    commands: int = 0
    resent: int = 0
    unacknowledged: int = 0
    command_error: str = ""
    reconnects: int = 0
    error: str = ""


@dataclass(frozen=True)
class ComponentState:
    """One component (a piece: a joint's two controllers share one id) as last heard.

    Attributes
    ----------
    id : int
    kind : str or None
        ``"joint"``, ``"splitter"``, ``"twist"`` (a joint's distal 0x84 controller heard on its own: the two
        halves do not share an id), ``"other"``, or None until an init or data record tells.
    node_type : int or None
        The firmware's node type from the last init record.
    colour : (int, int, int) or None
    parent : int or None
        0 for the host, None while unplaced (after a stale link was broken).
    slot : int
        Slot (splitter port) of the parent it is plugged into.
    attached : bool
        Heard within the timeout, with every ancestor attached.
    last_seen, last_heard : float
        Clock time of its last own record / of its last own or relayed record (-inf if never).
    attached_since : float
        When it last went from silent to heard.
    angles : (4,) ndarray or None
        A joint's last sensed angles, radians in record order (proximal twist, bend α, bend β, distal
        twist).
    raw : (4,) tuple of int or None
        The same as the u16 of the record.
    rotation : (4,) ndarray or None
        The joint's rotation (:func:`tangible.joint.joint_rotation` of ``angles``).
    data_time : float or None
        When ``angles`` arrived.
    slot_angles : Mapping[int, (3,) tuple] or None
        A splitter's outlets: slot → the three angles of its splitter records (radians).
    slot_rotations : (k, 4) ndarray or None
        The same as rotations of the outlets in the splitter's inlet frame, by slot
        (:func:`tangible.protocol.splitter_rotation`).
    frames : int
        Records it created that arrived.
    acks : int
        Commands it acknowledged; ``last_ack`` the last acknowledgement.
    attachments : int
        Times it (re-)attached.
    """

    id: int
    kind: str | None
    node_type: int | None
    colour: tuple[int, int, int] | None
    parent: int | None
    slot: int
    attached: bool
    last_seen: float
    last_heard: float
    attached_since: float
    angles: np.ndarray | None
    raw: tuple[int, int, int, int] | None
    rotation: np.ndarray | None
    data_time: float | None
    slot_angles: Mapping[int, tuple[float, float, float]] | None
    slot_rotations: np.ndarray | None
    frames: int
    acks: int
    last_ack: AckRecord | None
    attachments: int


@dataclass(frozen=True)
class DeviceState:
    """An immutable, consistent snapshot of the device.

    Attributes
    ----------
    time : float
        Clock time of the snapshot.
    connected : bool
        Whether the port was open.
    components : Mapping[int, ComponentState]
        Every component ever heard (attached or not).
    children : Mapping[int, tuple[int, ...]]
        Parent → attached children ordered by slot; key 0 is the host.
    link : LinkStats
    version : int
        Number of records applied so far; equal versions mean equal device data.
    """

    time: float
    connected: bool
    components: Mapping[int, ComponentState]
    children: Mapping[int, tuple[int, ...]]
    link: LinkStats = field(default_factory=LinkStats)
    version: int = 0

    @property
    def attached(self) -> tuple[int, ...]:
        """Attached component ids, depth first from the host, children by slot."""
        return self.subtree(0)[1:]

    def subtree(self, component: int) -> tuple[int, ...]:
        """``component`` and its attached descendants, depth first (0: the host and everything)."""
        out, stack = [], [component]
        while stack:
            c = stack.pop()
            out.append(c)
            stack.extend(reversed(self.children.get(c, ())))
        return tuple(out)

    def joint_angles(self, ids: Sequence[int]) -> np.ndarray:
        """(k, 4) last sensed angles of joints ``ids`` (record order).

        Raises
        ------
        DeviceError
            Naming the ids never heard or that sent no data yet.
        """
        return np.array([self._data(i).angles for i in ids], dtype=np.float64).reshape(-1, 4)

    def joint_rotations(self, ids: Sequence[int]) -> np.ndarray:
        """(k, 4) last rotations (quaternions) of joints ``ids``; raises like :meth:`joint_angles`."""
        return np.array([self._data(i).rotation for i in ids], dtype=np.float64).reshape(-1, 4)

    def _data(self, i: int) -> ComponentState:
        c = self.components.get(i)
        if c is None:
            raise DeviceError(f"component {i} was never heard")
        if c.angles is None or c.rotation is None:
            raise DeviceError(f"component {i} has sent no joint data")
        return c


def _kind(node_type: int) -> str:
    if node_type == NODE_JOINT_TUT_T:
        return "twist"
    if node_type & 0x0F == 0x04:
        return "joint"
    if node_type & 0x0F == 0x08:
        return "splitter"
    return "other"


class _Entry:
    __slots__ = (
        "acks",
        "angles",
        "attached_since",
        "attachments",
        "colour",
        "data_time",
        "frames",
        "id",
        "kind",
        "last_ack",
        "last_heard",
        "last_seen",
        "node_type",
        "parent",
        "raw",
        "slot",
        "slots",
    )

    def __init__(self, cid: int):
        self.id = cid
        self.kind: str | None = None
        self.node_type: int | None = None
        self.colour: tuple[int, int, int] | None = None
        self.parent: int | None = None
        self.slot = 0
        self.last_seen = -np.inf
        self.last_heard = -np.inf
        self.attached_since = -np.inf
        self.angles: tuple[float, ...] | None = None
        self.raw: tuple[int, ...] | None = None
        self.data_time: float | None = None
        self.slots: dict[int, tuple[float, float, float]] = {}
        self.last_ack: AckRecord | None = None
        self.frames = self.acks = self.attachments = 0


class DeviceTopology:
    """The parent→children table of a device, fed with decoded records.

    Parameters
    ----------
    timeout : float
        Seconds of silence after which a component and its subtree are detached (default 2 s).
    """

    def __init__(self, timeout: float = DETACH_TIMEOUT):
        if not timeout > 0:
            raise DeviceError(f"the detach timeout must be positive, got {timeout!r}")
        self.timeout = float(timeout)
        self.version = 0
        self._entries: dict[int, _Entry] = {}
        self._slots: dict[int, dict[int, int]] = {}  # parent -> slot -> child

    def parent(self, component: int) -> int | None:
        """Recorded parent of ``component`` (0: host, None: unplaced), attached or not."""
        return self._entry(component).parent

    def children(self, parent: int) -> tuple[int, ...]:
        """Recorded children of ``parent`` (0: host) by slot, attached or not."""
        slots = self._slots.get(parent, {})
        return tuple(slots[s] for s in sorted(slots))

    def _entry(self, component: int) -> _Entry:
        try:
            return self._entries[component]
        except KeyError:
            raise DeviceError(f"component {component} was never heard") from None

    def _get(self, cid: int) -> _Entry:
        e = self._entries.get(cid)
        if e is None:
            e = self._entries[cid] = _Entry(cid)
        return e

    def _hear(self, e: _Entry, now: float) -> None:
        if now - e.last_heard > self.timeout:
            e.attached_since = now
            e.attachments += 1
        e.last_heard = max(e.last_heard, now)

    def _unlink(self, e: _Entry) -> None:
        if e.parent is not None:
            slots = self._slots.get(e.parent)
            if slots is not None and slots.get(e.slot) == e.id:
                del slots[e.slot]
        e.parent = None

    def _place(self, e: _Entry, parent: int, slot: int) -> None:
        if e.parent == parent and e.slot == slot:
            return
        # A cycle means a stale link on the path parent -> ... -> e: break it just below e.
        node, below = parent, None
        while node not in (0, None):
            if node == e.id:
                self._unlink(self._entries[below])
                break
            below, node = node, self._entries[node].parent
        self._unlink(e)
        slots = self._slots.setdefault(parent, {})
        occupant = slots.get(slot)
        if occupant is not None and occupant != e.id:
            self._entries[occupant].parent = None
        slots[slot] = e.id
        e.parent, e.slot = parent, slot

    def observe(self, record: Record, now: float) -> None:
        """Apply one decoded record received at clock time ``now``."""
        r = record
        self_relayed = r.relayed and r.relayer == r.creator
        e = self._get(r.creator)
        e.frames += 1
        e.last_seen = max(e.last_seen, now)
        self._hear(e, now)
        if not self_relayed:
            if r.relayed:
                self._hear(self._get(r.relayer), now)
                self._place(e, r.relayer, r.port)
            else:
                self._place(e, 0, 0)
        if isinstance(r, DataRecord):
            if not self_relayed:  # in data mode 2 a joint's distal half speaks through its brother
                e.angles, e.raw, e.data_time = tuple(r.angles), r.raw, now
                if e.kind is None:
                    e.kind = "joint"
        elif isinstance(r, InitRecord):
            if not self_relayed:
                e.node_type, e.kind, e.colour = r.node_type, _kind(r.node_type), tuple(r.colour)
        elif isinstance(r, SplitterRecord):
            e.slots[r.slot] = tuple(r.angles)
        elif isinstance(r, AckRecord):
            e.acks += 1
            e.last_ack = r
        self.version += 1

    def attached(self, now: float) -> set[int]:
        """Ids attached at clock time ``now``."""
        memo: dict[int, bool] = {0: True}
        for cid in self._entries:
            path, node = [], cid
            while node not in memo:
                path.append(node)
                e = self._entries.get(node)
                if e is None or e.parent is None or now - e.last_heard > self.timeout:
                    memo[node] = False
                    path.pop()
                    break
                node = e.parent
            value = memo[node]
            for p in path:
                memo[p] = value
        return {c for c, ok in memo.items() if ok and c != 0}

    def snapshot(self, now: float, *, connected: bool = True, link: LinkStats | None = None) -> DeviceState:
        """An immutable :class:`DeviceState` as of clock time ``now``."""
        live = self.attached(now)
        joints = [e for e in self._entries.values() if e.angles is not None and e.kind == "joint"]
        rotations = joint_rotation(np.array([e.angles for e in joints])) if joints else np.empty((0, 4))
        rotation_of = {e.id: readonly(np.array(r)) for e, r in zip(joints, rotations, strict=True)}
        components = {}
        for e in self._entries.values():
            slots = dict(sorted(e.slots.items())) if e.slots else None
            components[e.id] = ComponentState(
                id=e.id,
                kind=e.kind,
                node_type=e.node_type,
                colour=e.colour,
                parent=e.parent,
                slot=e.slot,
                attached=e.id in live,
                last_seen=e.last_seen,
                last_heard=e.last_heard,
                attached_since=e.attached_since,
                angles=None if e.angles is None else readonly(np.array(e.angles)),
                raw=e.raw,
                rotation=rotation_of.get(e.id),
                data_time=e.data_time,
                slot_angles=None if slots is None else MappingProxyType(slots),
                slot_rotations=None
                if slots is None
                else readonly(splitter_rotation(np.array(list(slots.values())))),
                frames=e.frames,
                acks=e.acks,
                last_ack=e.last_ack,
                attachments=e.attachments,
            )
        children = {
            p: tuple(slots[s] for s in sorted(slots) if slots[s] in live)
            for p, slots in self._slots.items()
            if p == 0 or p in live
        }
        return DeviceState(
            time=now,
            connected=connected,
            components=MappingProxyType(components),
            children=MappingProxyType({p: c for p, c in children.items() if c}),
            link=link or LinkStats(),
            version=self.version,
        )
