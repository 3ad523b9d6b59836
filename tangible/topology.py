"""The host's picture of the device: a parent→children table built from messages (Appendix A).

:class:`DeviceTopology` is the mutable table; it is not thread-safe on its own (the
:class:`~tangible.reader.SerialReader` guards it with a lock) and needs no thread, so a recorded byte
stream can be replayed through it offline. :meth:`DeviceTopology.snapshot` returns an immutable
:class:`DeviceState`.

Rules (see ``PROTOCOL.md``, "Topology"):

* A message from ``c`` with parent ``p`` and slot ``s`` places ``c`` in slot ``s`` of ``p`` (``p = 0``:
  the host). A newer claim on an occupied slot, or one that would close a cycle, unlinks the stale entry,
  which stays unplaced (detached) until it speaks again.
* ``c`` is *heard* when it sends a message or when a message it relayed arrives (its id in the parent
  field proves it was powered and linked).
* ``c`` is **attached** when it was heard within ``timeout`` seconds (2 s by default) and its parent is
  the host or attached. So a component silent for longer than ``timeout`` is detached with its whole
  subtree, and re-attached as soon as it (or a child through it) speaks.
* Per-creator sequence numbers count lost frames: a forward step ``g`` (mod 65536) with ``1 ≤ g < 256``
  while the component was heard within ``timeout`` adds ``g − 1`` to ``dropped``; any other step counts
  as a restart (power cycle). The first message after a silence longer than ``timeout`` counts neither.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

from .errors import DeviceError
from .joint import joint_rotation
from .protocol import KIND_SPLITTER, ChildMessage, DataMessage, Message, TypeMessage

__all__ = ["DETACH_TIMEOUT", "ComponentState", "DeviceState", "DeviceTopology", "LinkStats"]

#: Seconds of silence after which a component and its subtree count as detached (Appendix A).
DETACH_TIMEOUT = 2.0
#: A forward sequence step at least this large (or a step back) is a restart, not lost frames.
SEQ_RESTART_GAP = 256


def _readonly(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class LinkStats:
    """Counters of the serial link (cumulative since the reader started).

    ``bytes``/``frames``/``corrupt``/``oversize``/``unsupported`` are the decoder's
    (:class:`tangible.protocol.DecoderStats`); ``reconnects`` counts successful re-openings of the port
    after it failed; ``error`` is the last port error in words ("" when none).
    """

    bytes: int = 0
    frames: int = 0
    corrupt: int = 0
    oversize: int = 0
    unsupported: int = 0
    reconnects: int = 0
    error: str = ""


@dataclass(frozen=True)
class ComponentState:
    """One component as last heard.

    Attributes
    ----------
    id : int
    kind : str or None
        ``"joint"``, ``"splitter"``, or None until a type or data message tells.
    colour : (int, int, int) or None
    parent : int or None
        0 for the host, None while unplaced (after a stale link was broken).
    slot : int
        Slot of the parent it is plugged into.
    attached : bool
        Heard within the timeout, with every ancestor attached.
    last_seen, last_heard : float
        Clock time of its last own message / of its last own or relayed message (-inf if never).
    attached_since : float
        When it last went from silent to heard.
    angles : (4,) ndarray or None
        A joint's last sensed angles ``(bend_a, bend_b, twist_proximal, twist_distal)``, radians.
    rotation : (4,) ndarray or None
        The same as a quaternion (:func:`tangible.joint.joint_rotation`).
    data_time : float or None
        When ``angles`` arrived.
    data_seq : int or None
        Sequence number of the data message ``angles`` came in.
    slot_rotations : (k, 4) ndarray or None
        A splitter's slot rotations (inlet frame to each outlet frame).
    frames, dropped, restarts, attachments : int
        Messages received, messages lost (sequence gaps), restarts seen, times it (re-)attached.
    """

    id: int
    kind: str | None
    colour: tuple[int, int, int] | None
    parent: int | None
    slot: int
    attached: bool
    last_seen: float
    last_heard: float
    attached_since: float
    angles: np.ndarray | None
    rotation: np.ndarray | None
    data_time: float | None
    data_seq: int | None
    slot_rotations: np.ndarray | None
    frames: int
    dropped: int
    restarts: int
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
        Number of messages applied so far; equal versions mean equal device data.
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
        """(k, 4) last sensed angles of joints ``ids``.

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
        if c.angles is None:
            raise DeviceError(f"component {i} has sent no joint data")
        return c


class _Entry:
    __slots__ = (
        "angles",
        "attached_since",
        "attachments",
        "colour",
        "data_seq",
        "data_time",
        "dropped",
        "frames",
        "id",
        "kind",
        "last_heard",
        "last_seen",
        "parent",
        "restarts",
        "seq",
        "slot",
        "slot_rotations",
    )

    def __init__(self, cid: int):
        self.id = cid
        self.kind: str | None = None
        self.colour: tuple[int, int, int] | None = None
        self.parent: int | None = None
        self.slot = 0
        self.last_seen = -np.inf
        self.last_heard = -np.inf
        self.attached_since = -np.inf
        self.seq: int | None = None
        self.angles: tuple[float, ...] | None = None
        self.data_time: float | None = None
        self.data_seq: int | None = None
        self.slot_rotations: tuple | None = None
        self.frames = self.dropped = self.restarts = self.attachments = 0


class DeviceTopology:
    """The parent→children table of a device, fed with decoded messages.

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

    def observe(self, message: Message, now: float) -> None:
        """Apply one decoded message received at clock time ``now``."""
        m = message
        if m.parent == m.creator:
            raise DeviceError(f"component {m.creator} cannot be its own parent")
        e = self._get(m.creator)
        if e.seq is not None and now - e.last_seen <= self.timeout:
            step = (m.seq - e.seq) % 65536
            if 1 <= step < SEQ_RESTART_GAP:
                e.dropped += step - 1
            else:
                e.restarts += 1
        e.seq = m.seq
        e.frames += 1
        e.last_seen = max(e.last_seen, now)
        self._hear(e, now)
        if m.parent != 0:
            self._hear(self._get(m.parent), now)
        self._place(e, m.parent, m.slot)
        if isinstance(m, DataMessage):
            e.angles, e.data_time, e.data_seq = m.angles, now, m.seq
            if e.kind is None:
                e.kind = "joint"
        elif isinstance(m, TypeMessage):
            e.kind = "splitter" if m.kind == KIND_SPLITTER else "joint"
            e.colour = m.colour
        elif isinstance(m, ChildMessage):
            e.slot_rotations = m.rotations
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
        joints = [e for e in self._entries.values() if e.angles is not None]
        rotations = joint_rotation(np.array([e.angles for e in joints])) if joints else np.empty((0, 4))
        rotation_of = {e.id: _readonly(r.copy()) for e, r in zip(joints, rotations, strict=True)}
        components = {
            e.id: ComponentState(
                id=e.id,
                kind=e.kind,
                colour=e.colour,
                parent=e.parent,
                slot=e.slot,
                attached=e.id in live,
                last_seen=e.last_seen,
                last_heard=e.last_heard,
                attached_since=e.attached_since,
                angles=None if e.angles is None else _readonly(np.array(e.angles)),
                rotation=rotation_of.get(e.id),
                data_time=e.data_time,
                data_seq=e.data_seq,
                slot_rotations=None if e.slot_rotations is None else _readonly(np.array(e.slot_rotations)),
                frames=e.frames,
                dropped=e.dropped,
                restarts=e.restarts,
                attachments=e.attachments,
            )
            for e in self._entries.values()
        }
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
