"""Device descriptions: splitter geometries and trees of pieces (joints and splitters).

A :class:`DeviceTree` is what the :class:`~tangible.simulator.Simulator` emulates, what the rig
reduction proposes (:attr:`tangible.reduction.Reduction.device`) and what the assembly instructions draw.
Piece ids are component ids (1 … :data:`tangible.protocol.MAX_ID`; the simulator, like the firmware,
needs :data:`~tangible.protocol.MIN_ID` or more); parent 0 is the host (the base the device is plugged
into), which takes one piece (slot 0). A joint has one outlet (slot 0); a splitter has the slots of its
:class:`SplitterType`.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field, replace
from types import MappingProxyType

import numpy as np

from . import rotations as rot
from .errors import RigError
from .protocol import MAX_ID

__all__ = ["PALETTE", "SPLITTERS", "DeviceTree", "Piece", "SplitterType"]

#: Distinct piece colours (8-bit RGB) used for planned devices and the simulator's defaults.
PALETTE: tuple[tuple[int, int, int], ...] = (
    (230, 25, 75),
    (60, 180, 75),
    (0, 130, 200),
    (245, 130, 48),
    (145, 30, 180),
    (70, 200, 200),
    (240, 50, 230),
    (170, 110, 40),
    (128, 0, 0),
    (0, 0, 128),
    (128, 128, 0),
    (0, 128, 128),
)


@dataclass(frozen=True)
class SplitterType:
    """A splitter geometry: one inlet along ``+y`` of the splitter frame and one outlet per slot.

    Attributes
    ----------
    name : str
    slots : (k, 4) ndarray
        Unit quaternions: slot ``i``'s outlet frame in the splitter (inlet) frame; the outlet shaft points
        along ``slots[i] ŷ``. Read-only.
    """

    name: str
    slots: np.ndarray = field(compare=False)

    def __post_init__(self):
        q = np.array(self.slots, dtype=np.float64).reshape(-1, 4)
        if not 1 <= len(q) <= 8 or not np.all(np.isfinite(q)):
            raise RigError(f"splitter {self.name!r} needs 1..8 finite slot quaternions, got shape {q.shape}")
        q = rot.normalize(q)
        q.setflags(write=False)
        object.__setattr__(self, "slots", q)

    @property
    def valence(self) -> int:
        """Number of outlets."""
        return len(self.slots)

    @property
    def directions(self) -> np.ndarray:
        """(k, 3) outlet shaft directions in the splitter frame."""
        return rot.rotate(self.slots, np.array([0.0, 1.0, 0.0]))

    @classmethod
    def planar(cls, name: str, degrees: Iterable[float]) -> SplitterType:
        """A splitter whose outlets lie in its x–y plane, turned by ``degrees`` about ``z`` from straight."""
        a = np.radians(np.asarray(list(degrees), dtype=np.float64))
        return cls(name, rot.from_axis_angle(np.array([0.0, 0.0, 1.0]), a))


#: The splitter kinds this project models (outlet angles from straight, in the splitter plane).
SPLITTERS: Mapping[str, SplitterType] = MappingProxyType(
    {
        "T": SplitterType.planar("T", [90.0, -90.0]),
        "Y": SplitterType.planar("Y", [45.0, -45.0]),
        "cross": SplitterType.planar("cross", [90.0, 0.0, -90.0]),
        "trident": SplitterType.planar("trident", [45.0, 0.0, -45.0]),
    }
)


@dataclass(frozen=True)
class Piece:
    """One piece of a device.

    Attributes
    ----------
    id : int
        Component id (1 … :data:`tangible.protocol.MAX_ID`).
    kind : str
        ``"joint"`` or ``"splitter"``.
    parent : int
        The piece it is plugged into, 0 for the host.
    slot : int
        The parent's slot (0 under a joint).
    colour : (int, int, int)
        8-bit RGB.
    splitter : SplitterType or None
        A splitter's geometry (None for joints).
    """

    id: int
    kind: str
    parent: int = 0
    slot: int = 0
    colour: tuple[int, int, int] = (200, 200, 200)
    splitter: SplitterType | None = None

    @property
    def valence(self) -> int:
        """Number of outlets: 1 for a joint."""
        return 1 if self.splitter is None else self.splitter.valence


class DeviceTree:
    """A validated tree of pieces.

    Parameters
    ----------
    pieces : iterable of Piece

    Raises
    ------
    RigError
        For repeated or out-of-range ids, an unknown kind, a splitter without geometry, a parent that is
        not in the tree, a slot the parent does not have, two pieces in one slot (the host has one), or a
        cycle; the message names the piece.
    """

    def __init__(self, pieces: Iterable[Piece]):
        pieces = tuple(pieces)
        by_id: dict[int, Piece] = {}
        for p in pieces:
            if not isinstance(p.id, int | np.integer) or not 1 <= int(p.id) <= MAX_ID:
                raise RigError(f"piece id {p.id!r} is outside 1..{MAX_ID}")
            if p.id in by_id:
                raise RigError(f"piece id {p.id} is used twice")
            if p.kind not in ("joint", "splitter"):
                raise RigError(f"piece {p.id} has kind {p.kind!r}; expected 'joint' or 'splitter'")
            if (p.kind == "splitter") != (p.splitter is not None):
                raise RigError(f"piece {p.id}: a splitter needs a SplitterType and a joint must not have one")
            by_id[int(p.id)] = p
        taken: dict[tuple[int, int], int] = {}
        for p in pieces:
            if p.parent == 0 and p.slot != 0:
                raise RigError(f"piece {p.id} is plugged into host slot {p.slot}; the host has one slot (0)")
            if p.parent != 0:
                parent = by_id.get(p.parent)
                if parent is None:
                    raise RigError(f"piece {p.id} is plugged into {p.parent}, which is not in the device")
                if not 0 <= p.slot < parent.valence:
                    raise RigError(
                        f"piece {p.id} is plugged into slot {p.slot} of piece {p.parent}, which has "
                        f"{parent.valence} slot(s)"
                    )
            if (p.parent, p.slot) in taken:
                raise RigError(
                    f"pieces {taken[p.parent, p.slot]} and {p.id} are both plugged into slot {p.slot} of "
                    f"{'the host' if p.parent == 0 else f'piece {p.parent}'}"
                )
            taken[p.parent, p.slot] = p.id
        self._by_id = by_id
        self._children: dict[int, tuple[Piece, ...]] = {}
        for p in sorted(pieces, key=lambda p: (p.parent, p.slot)):
            self._children[p.parent] = (*self._children.get(p.parent, ()), p)
        order = self._preorder()
        if len(order) != len(pieces):
            lost = sorted(set(by_id) - {p.id for p in order})
            raise RigError(f"pieces {lost} form a cycle (none of them leads to the host)")
        self._order = order

    def _preorder(self) -> tuple[Piece, ...]:
        out: list[Piece] = []
        stack = list(reversed(self._children.get(0, ())))
        while stack:
            p = stack.pop()
            out.append(p)
            stack.extend(reversed(self._children.get(p.id, ())))
        return tuple(out)

    def __iter__(self) -> Iterator[Piece]:
        """Pieces in depth-first order from the host, children by slot."""
        return iter(self._order)

    def __len__(self) -> int:
        return len(self._order)

    def __getitem__(self, piece_id: int) -> Piece:
        try:
            return self._by_id[piece_id]
        except KeyError:
            raise RigError(f"the device has no piece {piece_id}") from None

    def __contains__(self, piece_id: object) -> bool:
        return piece_id in self._by_id

    def children(self, piece_id: int) -> tuple[Piece, ...]:
        """Pieces plugged into ``piece_id`` (0: the host), ordered by slot."""
        return self._children.get(piece_id, ())

    def subtree(self, piece_id: int) -> tuple[int, ...]:
        """Ids of ``piece_id`` and everything plugged below it, depth first."""
        out, stack = [], [piece_id]
        while stack:
            p = stack.pop()
            out.append(p)
            stack.extend(c.id for c in reversed(self.children(p)))
        return tuple(out)

    def ancestors(self, piece_id: int) -> tuple[int, ...]:
        """Ids from the piece's parent up to the piece plugged into the host."""
        out, p = [], self[piece_id].parent
        while p != 0:
            out.append(p)
            p = self._by_id[p].parent
        return tuple(out)

    @property
    def joints(self) -> tuple[int, ...]:
        """Joint ids in depth-first order."""
        return tuple(p.id for p in self._order if p.kind == "joint")

    @property
    def splitters(self) -> tuple[int, ...]:
        """Splitter ids in depth-first order."""
        return tuple(p.id for p in self._order if p.kind == "splitter")

    def moved(self, piece_id: int, parent: int, slot: int = 0) -> DeviceTree:
        """A new tree with ``piece_id`` (and its subtree) unplugged and plugged into ``parent``/``slot``."""
        if piece_id not in self._by_id:
            raise RigError(f"the device has no piece {piece_id}")
        return DeviceTree(replace(p, parent=parent, slot=slot) if p.id == piece_id else p for p in self)
