"""Rig reduction (§3.2): which bones get the kit's joints, which branching nodes its splitters.

:func:`reduce` alternates the paper's two phases until the kit is used:

1. **Joints, greedily.** Try a joint on every free bone, minimize Eq. 1 for each candidate assignment
   (:func:`tangible.reachability.fit`, warm-started from the previous assignment's fit), keep the best,
   repeat while joints are left. Branching is ignored here.
2. **Splitters, by an integer program** (Eq. 2–5, :class:`SplitterProgram`, solved with
   ``scipy.optimize.milp``/HiGHS). For every undecided branching node ``n`` and splitter kind, every
   injective mapping of splitter slots to outlets of ``n`` is a candidate; the splitter's orientation is
   the Kabsch rotation best aligning its gates (inlet and mapped outlets) with the node's, and candidates
   whose matched gates are still more than 60° apart are dropped. The kit's joints are also available as
   *phantom splitters of valence 1* (keep one branch, unlimited). A candidate's gain is the drop in Eq. 1
   when the outlet chains it keeps, down to the next branching node, become free instead of rigid (all
   joints below ``n`` removed, the joints above re-fitted): one fit per outlet, summed over the kept
   outlets — their subtrees are disjoint, so with the joints above held fixed the drops add up exactly,
   and fitting each outlet alone keeps the systems small for long chains (a 40-bone tail). Ties go to
   the better-aligned geometry. Constraints: each splitter kind at
   most as often as the kit has it (Eq. 3, grouped by kind as the paper suggests), one candidate per node
   (Eq. 4), and a node only if its parent node keeps the outlet leading to it (Eq. 5).

Branches a decision does not keep are pruned — their joints go back to the kit for the next joint phase,
and their bones are driven later by pose-space interpolation. The device is then the sparse assignment
with the unassigned edges collapsed (:attr:`Reduction.device`).

Roots are posed externally (the device senses local rotations only), and a root node's inlet is not a
gate: the device base can be held any way round. With several roots the device serves the tree holding
the most node weight.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np
from scipy.optimize import Bounds, LinearConstraint, milp

from geodesics.rigid import kabsch

from . import rotations as rot
from .device import PALETTE, SPLITTERS, DeviceTree, Piece, SplitterType
from .errors import RigError
from .reachability import fit
from .skeleton import Skeleton

__all__ = [
    "PHANTOM",
    "BranchNode",
    "Candidate",
    "Kit",
    "Reduction",
    "SplitterProgram",
    "branch_nodes",
    "reduce",
    "splitter_candidates",
]

#: Candidates whose matched gates stay further apart than this after alignment are filtered out.
MAX_GATE_ERROR = np.radians(60.0)
#: A phantom splitter: one straight outlet, i.e. a joint continuing into one branch.
PHANTOM = SplitterType("phantom", [rot.IDENTITY])
_Y = np.array([0.0, 1.0, 0.0])


@dataclass(frozen=True)
class Kit:
    """The pieces available: ``joints`` and splitter counts by kind name (kinds from ``types``)."""

    joints: int
    splitters: Mapping[str, int] = field(default_factory=dict)
    types: Mapping[str, SplitterType] = field(default_factory=lambda: SPLITTERS)

    def __post_init__(self):
        if not isinstance(self.joints, int | np.integer) or self.joints < 0:
            raise RigError(f"a kit needs a non-negative number of joints, got {self.joints!r}")
        for name, count in self.splitters.items():
            if name not in self.types:
                raise RigError(f"unknown splitter kind {name!r}; known: {', '.join(self.types)}")
            if not isinstance(count, int | np.integer) or count < 0:
                raise RigError(f"splitter count for {name!r} must be a non-negative integer, got {count!r}")


@dataclass(frozen=True)
class BranchNode:
    """A bone with two or more children.

    Attributes
    ----------
    bone : int
    outlets : tuple of int
        Child bones.
    chains : tuple of tuple of int
        Per outlet, its bones down to the next branching bone or leaf (inclusive).
    parent : int
        The nearest branching ancestor's bone (-1 if none), and ``parent_outlet`` its outlet leading here.
    parent_outlet : int
    has_inlet : bool
        False at a root (the device base is free).
    directions : (v, 3) ndarray
        Outlet directions (the child bones' y axes) in the node bone's frame.
    """

    bone: int
    outlets: tuple[int, ...]
    chains: tuple[tuple[int, ...], ...]
    parent: int
    parent_outlet: int
    has_inlet: bool
    directions: np.ndarray = field(compare=False, repr=False)


def branch_nodes(skeleton: Skeleton) -> dict[int, BranchNode]:
    """Every branching bone of ``skeleton``, keyed by bone, parents first."""
    kids = skeleton.children
    M = skeleton.matrix_local[:, :3, :3]

    def chain(b: int) -> tuple[int, ...]:
        out = [b]
        while len(kids[out[-1]]) == 1:
            out.append(kids[out[-1]][0])
        return tuple(out)

    nodes: dict[int, BranchNode] = {}
    up: dict[int, tuple[int, int]] = {}  # bone -> (branching ancestor, outlet)
    for b in range(skeleton.n_bones):
        p = skeleton.parents[b]
        if p >= 0 and len(kids[p]) >= 2:
            up[b] = (p, kids[p].index(b))
        elif p >= 0:
            up[b] = up.get(p, (-1, -1))
        if len(kids[b]) >= 2:
            parent, outlet = up.get(b, (-1, -1))
            nodes[b] = BranchNode(
                bone=b,
                outlets=kids[b],
                chains=tuple(chain(c) for c in kids[b]),
                parent=parent,
                parent_outlet=outlet,
                has_inlet=p >= 0,
                directions=(M[b].T @ M[list(kids[b])])[:, :, 1],
            )
    return nodes


@dataclass(frozen=True)
class Candidate:
    """One way to put a splitter on a branching node.

    Attributes
    ----------
    node : int
        The branching bone.
    kind : str
        Splitter kind name, ``"phantom"`` for a phantom splitter.
    slots : tuple of int
        For each splitter slot, the outlet index of ``node`` it takes (-1: slot left empty).
    rotation : (4,) ndarray
        The splitter's Kabsch orientation in the node bone's frame.
    errors : (g,) ndarray
        Angle (radians) left between each matched gate pair: the inlet first (if the node has one), then
        the used slots in slot order.
    gain : float
        Drop in Eq. 1 when the kept chains become free (filled in by :func:`reduce`).
    """

    node: int
    kind: str
    slots: tuple[int, ...]
    rotation: np.ndarray = field(compare=False, repr=False)
    errors: np.ndarray = field(compare=False, repr=False)
    gain: float = 0.0

    @property
    def outlets(self) -> frozenset[int]:
        """Outlet indices kept."""
        return frozenset(s for s in self.slots if s >= 0)

    @property
    def phantom(self) -> bool:
        return self.kind == "phantom"


def splitter_candidates(node: BranchNode, kinds: Mapping[str, SplitterType]) -> list[Candidate]:
    """All candidates of ``node`` for splitter ``kinds`` (plus phantoms) that pass the 60° filter.

    Real splitters keep at least two outlets (one would waste a splitter on what a phantom does).
    """
    v = len(node.outlets)
    out: list[Candidate] = []
    for name, kind in [("phantom", PHANTOM), *kinds.items()]:
        k = kind.valence
        sizes = [1] if name == "phantom" else range(2, min(k, v) + 1)
        maps = []
        for s in sizes:
            for used in itertools.combinations(range(k), s):
                for outs in itertools.permutations(range(v), s):
                    slots = [-1] * k
                    for u, o in zip(used, outs, strict=True):
                        slots[u] = o
                    maps.append((used, outs, tuple(slots)))
        if not maps:
            continue
        for s in sizes:
            group = [m for m in maps if len(m[0]) == s]
            if not group:
                continue
            src = np.array([kind.directions[list(u)] for u, _, _ in group])  # (n, s, 3)
            dst = np.array([node.directions[list(o)] for _, o, _ in group])
            if node.has_inlet:
                src = np.concatenate([np.broadcast_to(_Y, (len(group), 1, 3)), src], axis=1)
                dst = np.concatenate([np.broadcast_to(_Y, (len(group), 1, 3)), dst], axis=1)
            R = kabsch(src, dst)
            moved = np.einsum("nij,nkj->nki", R, src)
            err = np.arccos(np.clip(np.sum(moved * dst, axis=-1), -1.0, 1.0))
            Q = rot.from_matrix(R)
            for i in np.flatnonzero(err.max(axis=1) <= MAX_GATE_ERROR):
                out.append(Candidate(node.bone, name, group[i][2], Q[i], err[i]))
    return out


@dataclass(frozen=True)
class SplitterProgram:
    """The integer program of Eq. 2–5: maximize ``gainᵀx`` over binary ``x`` with ``A x ≤ upper``.

    Attributes
    ----------
    candidates : tuple of Candidate
    objective : (n,) ndarray
        Gains minus a tie-break that prefers smaller gate errors (and no splitter over a useless one).
    A : (r, n) ndarray
    upper : (r,) ndarray
    rows : tuple of str
        What each row of ``A`` says, e.g. ``"Eq. 3: kind T"``, ``"Eq. 4: node 7"``,
        ``"Eq. 5: node 12 under outlet 1 of node 7"``.
    """

    candidates: tuple[Candidate, ...]
    objective: np.ndarray
    A: np.ndarray
    upper: np.ndarray
    rows: tuple[str, ...]

    @classmethod
    def build(
        cls,
        candidates: Sequence[Candidate],
        nodes: Mapping[int, BranchNode],
        counts: Mapping[str, int],
        undecided: set[int],
    ) -> SplitterProgram:
        """Assemble the program for ``candidates`` (gains filled in), the kit's splitter ``counts`` and
        the ``undecided`` branching bones (Eq. 5 ties a node to its parent node when that is undecided
        too; a node under a parent without candidates gets none either)."""
        cands = tuple(candidates)
        n = len(cands)
        gains = np.array([c.gain for c in cands])
        mean_err = np.array([float(np.mean(c.errors)) for c in cands])
        eps = 1e-6 * max(float(np.abs(gains).max(initial=0.0)), 1e-12)
        objective = gains - eps * (1.0 + mean_err / np.pi)
        rows, A, upper = [], [], []
        for name in sorted({c.kind for c in cands} - {"phantom"}):
            A.append([1.0 if c.kind == name else 0.0 for c in cands])
            upper.append(float(counts.get(name, 0)))
            rows.append(f"Eq. 3: kind {name}")
        present = sorted({c.node for c in cands})
        for node in present:
            A.append([1.0 if c.node == node else 0.0 for c in cands])
            upper.append(1.0)
            rows.append(f"Eq. 4: node {node}")
        for node in present:
            nd = nodes[node]
            if nd.parent not in undecided:
                continue
            A.append(
                [
                    (1.0 if c.node == node else 0.0)
                    - (1.0 if c.node == nd.parent and nd.parent_outlet in c.outlets else 0.0)
                    for c in cands
                ]
            )
            upper.append(0.0)
            rows.append(f"Eq. 5: node {node} under outlet {nd.parent_outlet} of node {nd.parent}")
        return cls(
            cands,
            objective,
            np.array(A, dtype=np.float64).reshape(len(rows), n),
            np.array(upper),
            tuple(rows),
        )

    def solve(self) -> np.ndarray:
        """Optimal binary ``x`` (n,) from HiGHS."""
        n = len(self.candidates)
        if n == 0:
            return np.zeros(0, bool)
        constraints = [LinearConstraint(self.A, -np.inf, self.upper)] if len(self.A) else []
        res = milp(-self.objective, integrality=np.ones(n), bounds=Bounds(0, 1), constraints=constraints)
        if res.x is None:
            raise RigError(f"the splitter assignment program failed: {res.message}")
        return np.round(res.x).astype(bool)

    def violations(self, x) -> list[str]:
        """The names (:attr:`rows`) of the rows of ``A x ≤ upper`` that binary ``x`` (n,) breaks (empty when
        feasible)."""
        x = np.asarray(x, dtype=np.float64)
        return [r for r, lhs, u in zip(self.rows, self.A @ x, self.upper, strict=True) if lhs > u + 1e-9]


@dataclass(frozen=True)
class Reduction:
    """A device configuration for a rig.

    Attributes
    ----------
    skeleton : Skeleton
    joints : tuple of int
        Bones with joints, in device (depth-first) order.
    splitters : tuple of Candidate
        Real splitters placed (each with its kind, slot mapping, orientation, gate errors and gain).
    phantoms : tuple of Candidate
        Branching nodes passed by a phantom splitter (one branch kept).
    pruned : tuple of int
        Bones cut off from the device (driven by pose interpolation).
    energy, baseline : float
        Eq. 1 (normalized, summed over poses) for this device and for no joints at all.
    pose_energy : (p,) ndarray
    rotations : (p, l, 4) ndarray
        Best joint rotations (bone local rotations) per sample pose, in ``joints`` order.
    device : DeviceTree
        Pieces to assemble (ids 1, 2, … in depth-first order).
    bones : Mapping[int, int]
        Piece id → bone (a joint's bone; a splitter's branching bone).
    rest : Mapping[int, ndarray]
        Joint piece id → the joint's reading when the rig is in its rest pose: the rest rotation of its
        bone relative to the piece it is plugged into (a splitter slot's offset from Kabsch included).
    program : SplitterProgram or None
        The last integer program solved, with its solution ``solution``.
    solution : ndarray or None
    rounds : int
        Joint/splitter phase pairs run.
    """

    skeleton: Skeleton
    joints: tuple[int, ...]
    splitters: tuple[Candidate, ...]
    phantoms: tuple[Candidate, ...]
    pruned: tuple[int, ...]
    energy: float
    baseline: float
    pose_energy: np.ndarray = field(repr=False)
    rotations: np.ndarray = field(repr=False)
    device: DeviceTree = field(repr=False)
    bones: Mapping[int, int] = field(repr=False)
    rest: Mapping[int, np.ndarray] = field(repr=False)
    program: SplitterProgram | None = field(repr=False)
    solution: np.ndarray | None = field(repr=False)
    rounds: int = 0

    @property
    def relative_error(self) -> float:
        """``energy / baseline``: the share of the rigid device's pose error left (Fig. 7)."""
        return self.energy / self.baseline if self.baseline > 0 else 0.0


def _main_tree(skeleton: Skeleton) -> np.ndarray:
    roots = skeleton.roots
    mass = skeleton.subtree[roots].astype(float) @ skeleton.weights
    return skeleton.subtree[roots[int(np.argmax(mass))]]


def reduce(
    skeleton: Skeleton,
    poses,
    kit: Kit,
    *,
    max_rounds: int = 8,
    max_iterations: int = 30,
    progress: Callable[[str], None] | None = None,
) -> Reduction:
    """Compute a device configuration for ``skeleton`` from sample ``poses`` (p, b, 4) and ``kit``.

    ``progress`` receives a short line of text before each phase.
    """
    say = progress or (lambda _msg: None)
    Q = skeleton.check_poses(poses, "sample poses")
    if Q.ndim != 3 or len(Q) == 0:
        raise RigError(f"need at least one sample pose of shape ({skeleton.n_bones}, 4), got {Q.shape}")
    nodes = branch_nodes(skeleton)
    tree = _main_tree(skeleton)
    usable = tree & (skeleton.parents >= 0)
    counts = {k: int(v) for k, v in kit.splitters.items() if v > 0}
    kinds = {k: kit.types[k] for k in counts}
    joints: list[int] = []
    warm = np.empty((len(Q), 0, 4))
    decided: dict[int, Candidate | None] = {}
    pruned = np.zeros(skeleton.n_bones, bool)
    program, solution = None, None
    baseline = float(fit(skeleton, Q, [[]]).energy[0])
    rounds = 0
    while kit.joints > 0 and rounds < max_rounds:
        rounds += 1
        while len(joints) < kit.joints:
            free = np.flatnonzero(usable & ~pruned & ~np.isin(np.arange(skeleton.n_bones), joints))
            if free.size == 0:
                break
            say(f"joint {len(joints) + 1} of {kit.joints}: trying {free.size} bones")
            nan = np.full((len(Q), 1, 4), np.nan)
            f = fit(
                skeleton,
                Q,
                [[*joints, int(b)] for b in free],
                init=[np.concatenate([warm, nan], axis=1)] * free.size,
                max_iterations=max_iterations,
            )
            best = int(np.argmin(f.energy))
            joints.append(int(free[best]))
            warm = f.rotations[best, :, : len(joints)]
        open_nodes = [nd for b, nd in nodes.items() if b not in decided and tree[b] and not pruned[b]]
        if not open_nodes:
            break
        say(f"splitters: {len(open_nodes)} branching nodes")
        program = _splitter_program(skeleton, Q, nodes, open_nodes, joints, kinds, counts, max_iterations)
        solution = program.solve()
        chosen = {c.node: c for c, x in zip(program.candidates, solution, strict=True) if x}
        for nd in open_nodes:
            c = chosen.get(nd.bone)
            decided[nd.bone] = c
            if c is not None and not c.phantom:
                counts[c.kind] -= 1
            for m, child in enumerate(nd.outlets):
                if c is None or m not in c.outlets:
                    pruned |= skeleton.subtree[child]
        keep = [i for i, b in enumerate(joints) if not pruned[b]]
        if len(keep) == len(joints):
            break
        joints = [joints[i] for i in keep]
        warm = warm[:, keep]
    return _finish(
        skeleton,
        Q,
        nodes,
        kit.types,
        joints,
        decided,
        pruned,
        baseline,
        program,
        solution,
        rounds,
        max_iterations,
    )


def _splitter_program(
    skeleton, Q, nodes, open_nodes, joints, kinds, counts, max_iterations
) -> SplitterProgram:
    candidates: list[Candidate] = []
    for nd in open_nodes:
        candidates.extend(splitter_candidates(nd, kinds))
    # Gains: per node, its all-rigid baseline and one fit per outlet chain made free; a candidate's gain
    # is the sum over the outlets it keeps (outlet subtrees are disjoint, so the drops add up).
    configs: list[list[int]] = []
    index: dict[tuple[int, int], int] = {}
    for nd in open_nodes:
        below = np.zeros(skeleton.n_bones, bool)
        for child in nd.outlets:
            below |= skeleton.subtree[child]
        context = [b for b in joints if not below[b]]
        index[nd.bone, -1] = len(configs)
        configs.append(context)
        for m in sorted({m for c in candidates if c.node == nd.bone for m in c.outlets}):
            index[nd.bone, m] = len(configs)
            configs.append(context + list(nd.chains[m]))
    energy = fit(skeleton, Q, configs, max_iterations=max_iterations).energy if configs else np.zeros(0)
    with_gain = [
        Candidate(
            c.node,
            c.kind,
            c.slots,
            c.rotation,
            c.errors,
            float(sum(energy[index[c.node, -1]] - energy[index[c.node, m]] for m in c.outlets)),
        )
        for c in candidates
    ]
    return SplitterProgram.build(with_gain, nodes, counts, {nd.bone for nd in open_nodes})


def _finish(
    skeleton, Q, nodes, types, joints, decided, pruned, baseline, program, solution, rounds, max_iterations
):
    jset = set(joints)
    pieces: list[Piece] = []
    bones: dict[int, int] = {}
    rest: dict[int, np.ndarray] = {}
    order: list[int] = []
    used_splitters: list[Candidate] = []
    phantoms: list[Candidate] = []
    M = skeleton.matrix_local[:, :3, :3]
    kids = skeleton.children
    has_joint_below = skeleton.subtree[:, joints].any(axis=1) if joints else np.zeros(skeleton.n_bones, bool)
    colour = itertools.cycle(PALETTE)

    def visit(b: int, parent: int, slot: int, frame: np.ndarray) -> None:
        """Place bone b's pieces under (parent piece, slot); ``frame`` is that slot's rest frame."""
        if b in jset:
            pid = len(pieces) + 1
            pieces.append(Piece(pid, "joint", parent, slot, next(colour)))
            bones[pid] = b
            rest[pid] = rot.from_matrix(frame.T @ M[b])
            order.append(b)
            parent, slot, frame = pid, 0, M[b]
        if b in nodes:
            c = decided.get(b)
            if c is None:
                return
            if not any(has_joint_below[nodes[b].outlets[m]] for m in c.outlets):
                return
            if c.phantom:
                phantoms.append(c)
                (m,) = c.outlets
                visit(nodes[b].outlets[m], parent, slot, frame)
                return
            kind = types[c.kind]
            sid = len(pieces) + 1
            pieces.append(Piece(sid, "splitter", parent, slot, next(colour), splitter=kind))
            bones[sid] = b
            used_splitters.append(c)
            orient = M[b] @ rot.to_matrix(c.rotation)
            for s, m in enumerate(c.slots):
                if m >= 0:
                    visit(nodes[b].outlets[m], sid, s, orient @ rot.to_matrix(kind.slots[s]))
            return
        for child in kids[b]:
            if not pruned[child]:
                visit(child, parent, slot, frame)

    root = int(skeleton.roots[np.argmax(skeleton.subtree[skeleton.roots].astype(float) @ skeleton.weights)])
    visit(root, 0, 0, M[root])
    f = fit(skeleton, Q, [order], max_iterations=max_iterations)
    return Reduction(
        skeleton=skeleton,
        joints=tuple(order),
        splitters=tuple(used_splitters),
        phantoms=tuple(phantoms),
        pruned=tuple(int(b) for b in np.flatnonzero(pruned)),
        energy=float(f.energy[0]),
        baseline=baseline,
        pose_energy=f.pose_energy[0],
        rotations=f.rotations[0],
        device=DeviceTree(pieces),
        bones=MappingProxyType(bones),
        rest=MappingProxyType(rest),
        program=program,
        solution=solution,
        rounds=rounds,
    )
