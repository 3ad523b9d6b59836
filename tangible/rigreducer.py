"""Interoperability with the authors' rig reducer (``oliglauser/atamid``, ``Software/RigReducer``): read its
inputs into a :class:`~tangible.Skeleton`, write rigs it can read, and write its outputs from our
:func:`~tangible.reduce`, so a rig prepared for one works with the other and the two reductions can be
compared on the same rig.

**Their files** (``reduceModel.cpp`` ``load_model``/``load_poses``; ``reducer3.cpp`` ``ExportSetup``). The
reducer is started on a mesh ``X.obj`` (or ``.off``, ``.ply``) and derives every other name from ``X``:

==========================  ==============================================================================
``X.tgf``                   the skeleton: nodes (points) and edges (bones, node to node); libigl's
                            ``readTGF``
``X-weights.dmat``          skin weights, one row per mesh vertex; one column per edge (**bone mode**,
                            libigl's convention) or, when there are at least as many columns as nodes, one
                            per node (**node mode**, Maya's: a node is a joint and turns the edges leaving
                            it; the reducer then adds an end node 20% beyond every leaf, on the leaf's
                            edge, turned by the leaf)
``X-pose-NNNN.dmat``        sample poses, ``0000``, ``0001``, … up to the first missing number; each the
                            stacked transposed affine transforms of libigl's ``lbs_matrix``: 4 rows per
                            edge (bone mode) or per node (node mode), ``[Aᵀ; tᵀ]``, so that a point ``x``
                            of the bone moves to ``A x + t`` (``A`` the bone's rotation in world space,
                            from rest to pose)
``X-localcos.dmat``         written: ``3N × 3``, ``N`` the nodes (node mode: with the end nodes); rows
                            ``3h … 3h+2`` hold, for the device joint on the edge leaving node ``h``, the
                            rest frame of the link after the joint (rotation matrix: columns are the link's
                            axes in world coordinates, ``x`` along the bone); zero for edges without a joint
``X-restpose.dmat``         written: ``3N × 3``, same rows: the joint's rest rotation in world coordinates,
                            ``localcos = restpose · (inlet frame)``
``X-splitgeo.dmat``         written: ``k × 5``, one row per device link: ``[h_parent, h_child, roll, pitch,
                            yaw]``; first, per splitter, one row per slot (``h_child = −1`` for an empty
                            slot) with the slot's outlet frame ``Rz(yaw) Ry(pitch) Rx(roll)`` in the
                            splitter frame (radians, inlet along ``x``); then one row ``[h_parent, h_child,
                            0, 0, 0]`` per joint plugged into a joint or into the base
==========================  ==============================================================================

A joint is keyed by the **head node** ``h`` of its bone (a Maya joint is the node that turns the bone),
``h_parent`` is the key of the joint before it (the root node for the base). Joints on two bones leaving
the same node share a key: as in their ``ExportSetup``, the later edge's block is the one written (their
node mode never places such joints: the children of a branching node are kept rigid there, ``reducer3.cpp``
lines 175–197; in bone mode their own output loses one the same way). Their reducer also writes the zero
block of a jointless edge over a jointed sibling's when it comes later in the file; ours never overwrites
a joint's block with zeros. The rows their ``ExportSetup`` leaves uninitialized (leaves) are zero here. A
splitter plugged straight into a splitter slot (their reducer never makes one; ours can) is keyed by the
head node of its branching bone.

The libigl files themselves (``.dmat``, ``.tgf``) are read and written by :mod:`tangible.libigl_files`,
whose functions this module exports too.

**Their conventions and ours.** Bones are edges, head at the first node, tail at the second; coordinates
are copied as they are (world = armature space). A bone's parent is the bone whose tail is its head
node. Their frames put the bone along ``x``, ours (Blender's) along ``y``: a frame's axes in ours are
theirs relabelled by :data:`tangible.joint.THEIR_AXES` (our ``x, y, z`` = their ``z, x, y``). A pose's
local rotation of bone ``b`` (ours, in its rest frame ``R_b``) is ``R_bᵀ A_pᵀ A_b R_b`` with ``A_p`` the
parent bone's transform (``R_bᵀ A_b R_b`` for roots); translations are dropped, as the device senses
rotations only. Our node weights are the area each bone controls (:func:`~tangible.area_weights` of the
mesh); their node importances, vertex areas (sum of incident triangles) times skin weights, are three
times ours for skin weights summing to one.

Link frames and rest rotations: ours carry the skeleton's bone rolls (a link's frame is its bone's rest
frame, relabelled: their ``x, y, z`` = our ``y, z, x``) and a joint's rest rotation is the one
:func:`~tangible.reduce` plans (:attr:`Reduction.rest <tangible.reduction.Reduction.rest>`, rolls between
consecutive bones included); theirs carry a frame from the root by shortest arcs (the rest rotations are
shortest arcs, plus a twist before a splitter). The two agree on each link's ``x`` axis (the bone's
direction) and differ by a roll about it; :meth:`ReducerSetup.rest_readings` gives either file's rest
rotations as our joint readings.

What their files cannot hold, and how we write it: bone names go after a bone's tail coordinates (which
libigl ignores); a bone whose head is not its parent's tail hangs from a **pseudo edge** (flag ``0 1 0``)
from the parent's tail to its head, with a zero weight column and the parent's transform — their reducer
takes it for a bone of no importance that moves with its parent (libigl warns that it does not support
pseudo edges and keeps it as an edge), we read it back as the offset it is; rest frames (roll) go to
``X-zaxes.dmat`` (one row per bone edge, its rest ``z`` axis), which their reducer ignores and without
which a bone's roll follows :meth:`Skeleton.from_heads_tails`. Their reducer wants one root node and, in
bone mode, that root to be node 0 (its pose block is replaced by the identity) and edge ``j`` to end at
node ``j + 1`` (the importances are indexed so); :func:`write_rig` numbers the nodes so.
"""

from __future__ import annotations

import heapq
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import rotations as rot
from .errors import RigError
from .joint import THEIR_AXES
from .libigl_files import (
    TGF,
    TGF_LINE_BYTES,
    dmat_columns,
    format_dmat,
    format_tgf,
    parse_dmat,
    parse_tgf,
    read_dmat,
    read_tgf,
    write_dmat,
    write_obj,
    write_tgf,
)
from .reduction import Reduction
from .skeleton import Skeleton, area_weights

__all__ = [
    "TGF",
    "ReducerSetup",
    "format_dmat",
    "format_tgf",
    "parse_dmat",
    "parse_tgf",
    "read_dmat",
    "read_reduction",
    "read_rig",
    "read_tgf",
    "write_dmat",
    "write_reduction",
    "write_rig",
    "write_tgf",
]

#: Mesh file extensions the reducer accepts, in the order :func:`read_rig` looks for them.
MESH_EXTENSIONS = (".obj", ".off", ".ply")
#: Relative tolerance (of the skeleton's size) for points that coincide (a child's head at its parent's
#: tail, a bone matched to a file's edge).
COINCIDE = 1e-9


# ================================================================== their rig as bones


@dataclass(frozen=True)
class _Bones:
    """A rig file's bones, parents first: where each sits in their arrays."""

    nodes: np.ndarray  # (N, 3) all nodes, node mode's end nodes appended
    root: int  # the root node
    head: np.ndarray  # (b,) head node of each bone
    tail: np.ndarray  # (b,) tail node
    edge: np.ndarray  # (b,) their edge index (node mode's end edges numbered after the file's)
    parents: np.ndarray  # (b,) parent bone, -1 for roots
    names: tuple[str, ...]
    transform: np.ndarray  # (b,) which 4-row block of a pose file moves the bone
    column: np.ndarray  # (b,) which weights column is the bone's
    node_mode: bool


def _bones(tgf: TGF, n_columns: int | None, where: str) -> _Bones:
    """A rig file's bones (node mode when the weights have a column per node), checked to form one tree."""
    n, m = len(tgf.nodes), len(tgf.edges)
    if m == 0:
        raise RigError(f"{where}: the skeleton has no edges")
    node_mode = _node_mode(n, m, n_columns, where)
    root, incoming, children = _tree(tgf.edges, n, where)
    all_nodes, heads_e, tails_e = _edges_with_ends(tgf, incoming, children, node_mode, where)
    pseudo = tgf.pseudo if not node_mode else np.zeros(m, bool)
    order, parent_edge = _parents_first(heads_e, tails_e, pseudo, m, len(all_nodes))
    position = {e: i for i, e in enumerate(order)}
    names = _bone_names(tgf, order, heads_e, tails_e, where)
    head = heads_e[order]
    return _Bones(
        nodes=all_nodes,
        root=root,
        head=head,
        tail=tails_e[order],
        edge=np.array(order),
        parents=np.array([position.get(parent_edge[e], -1) for e in order]),
        names=names,
        transform=head.copy() if node_mode else np.array(order),
        column=head.copy() if node_mode else np.array(order),
        node_mode=node_mode,
    )


def _node_mode(n: int, m: int, n_columns: int | None, where: str) -> bool:
    """Whether weights with ``n_columns`` columns (None: no weights file) are per node (Maya's joint weights)
    rather than per edge (libigl's bone weights), for ``n`` nodes and ``m`` edges."""
    if n_columns is None or (n_columns == m and m < n):
        node_mode = False
    elif n_columns == n:
        node_mode = True
    else:
        raise RigError(
            f"{where}: the weights have {n_columns} columns; expected one per edge ({m}, libigl's bone "
            f"weights) or one per node ({n}, Maya's joint weights)"
        )
    return node_mode


def _tree(E: np.ndarray, n: int, where: str) -> tuple[int, np.ndarray, list[list[int]]]:
    """The root node of the edges E (m, 2) on ``n`` nodes, the edge ending at each node (-1 at the root)
    and the edges leaving it; a RigError unless they form one tree over every node."""
    incoming = np.full(n, -1)
    for e, (_, t) in enumerate(E):
        if incoming[t] >= 0:
            raise RigError(
                f"{where}: node {t + 1} ends two edges ({incoming[t] + 1} and {e + 1}); a skeleton is a tree"
            )
        incoming[t] = e
    used = np.zeros(n, bool)
    used[E.ravel()] = True
    if not used.all():
        raise RigError(f"{where}: node {int(np.flatnonzero(~used)[0]) + 1} is on no edge")
    roots = np.flatnonzero(incoming < 0)
    if len(roots) != 1:
        if len(roots) == 0:
            raise RigError(f"{where}: the edges form a cycle (every node ends an edge)")
        raise RigError(
            f"{where}: nodes {', '.join(str(r + 1) for r in roots)} start separate trees; expected one root"
        )
    # Every node must lead up to the root (no cycles off the root's tree).
    depth = np.full(n, -1)
    depth[roots[0]] = 0
    children: list[list[int]] = [[] for _ in range(n)]
    for e, (h, _) in enumerate(E):
        children[h].append(e)
    stack = [int(roots[0])]
    while stack:
        h = stack.pop()
        for e in children[h]:
            t = int(E[e, 1])
            depth[t] = depth[h] + 1
            stack.append(t)
    if np.any(depth < 0):
        lost = np.flatnonzero(depth < 0) + 1
        shown = ", ".join(map(str, lost[:6])) + (", …" if len(lost) > 6 else "")
        raise RigError(f"{where}: nodes {shown} form a cycle apart from the root")
    return int(roots[0]), incoming, children


def _edges_with_ends(
    tgf: TGF, incoming: np.ndarray, children: list[list[int]], node_mode: bool, where: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All nodes (N, 3) and the head and tail node of every edge: the file's, and in node mode an end node
    20% beyond every leaf on its edge, with an edge from the leaf to it (numbered after the file's); a
    RigError for an edge of zero length."""
    E, nodes, n = tgf.edges, tgf.nodes, len(tgf.nodes)
    heads_e, tails_e = E[:, 0].tolist(), E[:, 1].tolist()
    all_nodes = nodes
    if node_mode:
        leaves = [i for i in range(n) if not children[i]]
        ends = np.array([0.2 * (nodes[i] - nodes[E[incoming[i], 0]]) + nodes[i] for i in leaves]).reshape(
            -1, 3
        )
        all_nodes = np.concatenate([nodes, ends])
        heads_e += leaves
        tails_e += list(range(n, n + len(leaves)))
    heads_e, tails_e = np.array(heads_e), np.array(tails_e)
    lengths = np.linalg.norm(all_nodes[tails_e] - all_nodes[heads_e], axis=1)
    bad = np.flatnonzero(~(lengths > 0))
    if bad.size:
        e = int(bad[0])
        raise RigError(f"{where}: edge {e + 1} (nodes {heads_e[e] + 1} to {tails_e[e] + 1}) has zero length")
    return all_nodes, heads_e, tails_e


def _parents_first(
    heads_e: np.ndarray, tails_e: np.ndarray, pseudo: np.ndarray, m: int, n_nodes: int
) -> tuple[list[int], dict[int, int]]:
    """The bone edges (all but the file's ``m`` edges' ``pseudo`` ones), parents first in a stable
    topological order that keeps file order where it allows, and each one's parent bone edge (through
    pseudo edges; -1 for a root)."""
    # Bone edges and their parent bone edges (through pseudo edges).
    bone_edges = [e for e in range(len(heads_e)) if e >= m or not pseudo[e]]
    incoming_all = np.full(n_nodes, -1)
    incoming_all[tails_e] = np.arange(len(tails_e))
    parent_edge = {}
    for e in bone_edges:
        p = incoming_all[heads_e[e]]
        while p >= 0 and p < m and pseudo[p]:
            p = incoming_all[heads_e[p]]
        parent_edge[e] = int(p)
    # Parents first, keeping file order where it allows (a stable topological order).
    kids: dict[int, list[int]] = {}
    for e in bone_edges:
        kids.setdefault(parent_edge[e], []).append(e)
    heap = list(kids.get(-1, []))
    heapq.heapify(heap)
    order: list[int] = []
    while heap:
        e = heapq.heappop(heap)
        order.append(e)
        for k in kids.get(e, []):
            heapq.heappush(heap, k)
    return order, parent_edge


def _bone_names(
    tgf: TGF, order: list[int], heads_e: np.ndarray, tails_e: np.ndarray, where: str
) -> tuple[str, ...]:
    """Each bone's name, in ``order``: its tail node's label, ``<head label>.end`` (or ``end<head>``) for
    node mode's end bones, else ``bone<edge>``; a RigError for repeated names."""
    n = len(tgf.nodes)
    names = []
    for e in order:
        t = int(tails_e[e])
        if t < n and tgf.labels[t]:
            names.append(tgf.labels[t])
        elif t >= n:
            h = int(heads_e[e])
            names.append(f"{tgf.labels[h]}.end" if tgf.labels[h] else f"end{h}")
        else:
            names.append(f"bone{e}")
    if len(set(names)) != len(names):
        dup = sorted({x for x in names if names.count(x) > 1})
        raise RigError(f"{where}: bone names must be unique; repeated: {', '.join(map(repr, dup[:6]))}")
    return tuple(names)


def _prefix(prefix) -> str:
    return os.fspath(prefix)


def _pose_paths(prefix: str) -> list[Path]:
    out = []
    while (p := Path(f"{prefix}-pose-{len(out):04d}.dmat")).exists():
        out.append(p)
    return out


def read_rig(prefix, *, mesh=None) -> tuple[Skeleton, np.ndarray, np.ndarray]:
    """Read a rig prepared for their reducer: ``prefix.tgf``, ``prefix-weights.dmat``,
    ``prefix-pose-NNNN.dmat`` (and ``prefix-zaxes.dmat``, the rest z axes :func:`write_rig` writes, if
    there is one: a stale one from another rig is refused when its row count differs, else applied).

    Parameters
    ----------
    prefix : str or os.PathLike
        The files' common beginning (their mesh's path without its extension).
    mesh : str or os.PathLike, optional
        The skinned mesh, for the node weights; by default ``prefix.obj``, ``.off`` or ``.ply``, the first
        that exists (read by :func:`geodesics.load_mesh`, whose checks apply). Without one the node
        weights are the bones' lengths.

    Returns
    -------
    skeleton : Skeleton
        Bones parents first (file order where it allows), named by their tail node's label or
        ``bone<edge index>``; node mode adds the end bones (``<name>.end``).
    poses : (p, b, 4)
        Local rotations (quaternions) of every sample pose.
    weights : (v, b)
        Skin weights, one column per bone.

    Raises
    ------
    RigError
        For a missing or malformed file, naming the file.
    """
    prefix = _prefix(prefix)
    tgf = read_tgf(f"{prefix}.tgf")
    wpath = Path(f"{prefix}-weights.dmat")
    W = read_dmat(wpath)
    if not np.all(np.isfinite(W)):
        raise RigError(f"{wpath}: non-finite weights")
    bones = _bones(tgf, W.shape[1], f"{prefix}.tgf")
    weights = W[:, bones.column]
    heads, tails = bones.nodes[bones.head], bones.nodes[bones.tail]
    z_axes = None
    zpath = Path(f"{prefix}-zaxes.dmat")
    if zpath.exists():
        Z = read_dmat(zpath)
        n_bone_edges = int((~tgf.pseudo).sum())
        if Z.shape != (n_bone_edges, 3) or bones.node_mode:
            raise RigError(
                f"{zpath}: expected one row (x, y, z) per bone edge of {prefix}.tgf in bone mode, shape "
                f"({n_bone_edges}, 3), got {Z.shape}"
            )
        z_axes = Z[np.argsort(np.argsort(bones.edge))]  # rows: bone edges in file order
        if not np.all(np.isfinite(z_axes)):
            raise RigError(f"{zpath}: non-finite z axes")
    node_weights = None
    mesh_path = _find_mesh(prefix) if mesh is None else Path(mesh)
    if mesh_path is not None:
        V, F = _load_mesh(mesh_path)
        if len(V) != len(W):
            raise RigError(f"{wpath}: {len(W)} rows of weights for the {len(V)} vertices of {mesh_path}")
        node_weights = area_weights(V, F, weights)
    try:
        skeleton = Skeleton.from_heads_tails(bones.names, bones.parents, heads, tails, z_axes, node_weights)
    except RigError as err:
        raise RigError(f"{prefix}.tgf: {err}", bones=err.bones) from None
    poses = [_read_pose(p, bones, skeleton, W.shape[1]) for p in _pose_paths(prefix)]
    return skeleton, np.array(poses).reshape(-1, skeleton.n_bones, 4), weights


def _find_mesh(prefix: str) -> Path | None:
    for ext in MESH_EXTENSIONS:
        if (p := Path(prefix + ext)).exists():
            return p
    return None


def _load_mesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    from geodesics import load_mesh
    from geodesics.errors import MeshError

    try:
        m = load_mesh(path)
    except MeshError as err:
        raise RigError(str(err)) from None
    return np.asarray(m.vertices), np.asarray(m.faces)


def _read_pose(path: Path, bones: _Bones, skeleton: Skeleton, n_transforms: int) -> np.ndarray:
    T = read_dmat(path)
    if T.shape != (4 * n_transforms, 3):
        raise RigError(
            f"{path}: expected 4 rows per {'node' if bones.node_mode else 'edge'} and 3 columns, shape "
            f"({4 * n_transforms}, 3), got {T.shape}"
        )
    if not np.all(np.isfinite(T)):
        raise RigError(f"{path}: non-finite values")
    A = np.swapaxes(T.reshape(n_transforms, 4, 3)[:, :3], 1, 2)  # (k, 3, 3) rotations, world
    off = np.abs(np.swapaxes(A, 1, 2) @ A - np.eye(3)).max(axis=(1, 2))
    bad = np.flatnonzero(~(off < 1e-6) | ~(np.linalg.det(A) > 0))
    if bad.size:
        k = int(bad[0])
        what = f"node {k + 1}" if bones.node_mode else f"edge {k + 1}"
        raise RigError(f"{path}: rows {4 * k + 1} to {4 * k + 3} ({what}) are not a rotation (transposed)")
    Ab = A[bones.transform]
    has = skeleton.parents >= 0
    Ap = np.broadcast_to(np.eye(3), Ab.shape).copy()
    Ap[has] = Ab[skeleton.parents[has]]
    R = skeleton.matrix_local[:, :3, :3]
    local = np.swapaxes(R, 1, 2) @ np.swapaxes(Ap, 1, 2) @ Ab @ R
    return rot.from_matrix(local)


# ================================================================== our rig in their files


@dataclass(frozen=True)
class _Numbering:
    """Our skeleton in their files: nodes, edges (bone or pseudo) and each bone's edge."""

    tgf: TGF
    bone_edge: np.ndarray  # (b,) edge of each bone
    edge_bone: np.ndarray  # (m,) bone an edge moves with (a pseudo edge: the parent's)


def _numbering(skeleton: Skeleton) -> _Numbering:
    tol = COINCIDE * skeleton.size
    heads = skeleton.matrix_local[:, :3, 3]
    tails = skeleton.rest_tails
    roots = skeleton.roots
    far = roots[np.linalg.norm(heads[roots] - heads[roots[0]], axis=1) > tol]
    if far.size:
        raise RigError(
            f"bones {skeleton._list(np.concatenate([roots[:1], far]))} are roots with different heads; "
            "their reducer needs a single root node",
            bones=np.concatenate([roots[:1], far]),
        )
    nodes = [heads[roots[0]]]
    labels = [""]
    edges, flags, edge_bone = [], [], []
    tail_node = np.zeros(skeleton.n_bones, np.int64)
    bone_edge = np.zeros(skeleton.n_bones, np.int64)
    offsets: dict[tuple[int, bytes], int] = {}
    for b in range(skeleton.n_bones):
        p = skeleton.parents[b]
        if p < 0:
            head = 0
        elif np.linalg.norm(heads[b] - tails[p]) <= tol:
            head = int(tail_node[p])
        else:
            key = (int(p), heads[b].tobytes())
            if key not in offsets:
                edges.append([int(tail_node[p]), len(nodes)])
                flags.append([0, 1, 0])
                edge_bone.append(int(p))
                nodes.append(heads[b])
                labels.append("")
                offsets[key] = len(nodes) - 1
            head = offsets[key]
        bone_edge[b] = len(edges)
        edges.append([head, len(nodes)])
        flags.append([1, 0, 0])
        edge_bone.append(b)
        tail_node[b] = len(nodes)
        nodes.append(tails[b])
        labels.append(_label(skeleton, b, len(nodes), tails[b]))
    tgf = TGF(np.array(nodes), np.array(edges), np.array(flags), tuple(labels))
    return _Numbering(tgf, bone_edge, np.array(edge_bone))


def _label(skeleton: Skeleton, b: int, node: int, position: np.ndarray) -> str:
    """Bone ``b``'s name as the label of its tail, ``node`` (1-based), or a RigError."""
    name = skeleton.names[b]
    if not name or name != name.strip() or "\n" in name or "\r" in name:
        raise RigError(
            f"bone {b} {name!r}: a .tgf label cannot be empty, start or end with white space, or span lines",
            bones=[b],
        )
    line = f"{node:4d} {position[0]:.17g} {position[1]:.17g} {position[2]:.17g} {name}\n"
    if len(line.encode("utf-8")) > TGF_LINE_BYTES:
        raise RigError(f"bone {b} {name!r}: the name is too long for libigl's 499-byte .tgf lines", bones=[b])
    return name


def write_rig(prefix, skeleton: Skeleton, poses, weights=None, mesh=None) -> None:
    """Write a rig their reducer reads: ``prefix.tgf``, ``prefix-weights.dmat``, ``prefix-pose-NNNN.dmat``
    (bone mode), ``prefix-zaxes.dmat`` (rest z axes, for :func:`read_rig`) and, unless ``weights`` is given
    without ``mesh``, the mesh ``prefix.obj``.

    Parameters
    ----------
    prefix : str or os.PathLike
    skeleton : Skeleton
        Its roots must share one head.
    poses : (p, b, 4) array_like
        Local rotations of the sample poses.
    weights : (v, b) array_like, optional
        Skin weights of ``mesh``'s vertices. Without them each bone with a positive node weight gets a
        triangle of that area at its tail, skinned to it alone, so that the mesh's area weights (ours, and
        theirs up to the factor 3) are the skeleton's node weights.
    mesh : (vertices (v, 3), faces (f, 3)), optional
        The skinned mesh (needed with ``weights`` to write ``prefix.obj``).

    Raises
    ------
    RigError
        For a skeleton their files cannot hold (roots apart, unwritable names), bad poses or weights, or a
        file that cannot be written.
    """
    prefix = _prefix(prefix)
    num = _numbering(skeleton)
    Q = skeleton.check_poses(poses, "sample poses")
    if Q.ndim != 3:
        raise RigError(f"sample poses must have shape (p, {skeleton.n_bones}, 4), got {Q.shape}")
    stale = Path(f"{prefix}-pose-{len(Q):04d}.dmat")
    if stale.exists():
        raise RigError(
            f"{stale}: a pose file of an earlier rig would follow the {len(Q)} poses; remove it first"
        )
    if weights is None:
        if mesh is not None:
            raise RigError("a mesh needs its skin weights (v, b)")
        V, F, W = _weight_triangles(skeleton)
    else:
        W = np.asarray(weights, dtype=np.float64)
        if W.ndim != 2 or W.shape[1] != skeleton.n_bones or not np.all(np.isfinite(W)):
            raise RigError(f"skin weights must be finite with shape (v, {skeleton.n_bones}), got {W.shape}")
        V = F = None
        if mesh is not None:
            V, F = (np.asarray(a) for a in mesh)
            if V.ndim != 2 or V.shape[1] != 3 or len(V) != len(W) or F.ndim != 2 or F.shape[1] != 3:
                raise RigError(f"mesh must be vertices ({len(W)}, 3) and triangles (f, 3)")
    m = len(num.tgf.edges)
    Wm = np.zeros((len(W), m))
    Wm[:, num.bone_edge] = W
    write_tgf(f"{prefix}.tgf", num.tgf)
    write_dmat(f"{prefix}-weights.dmat", Wm)
    write_dmat(f"{prefix}-zaxes.dmat", skeleton.matrix_local[:, :3, 2])
    if V is not None:
        write_obj(Path(f"{prefix}.obj"), V, F)
    posed = skeleton.forward(Q)
    R = skeleton.matrix_local[:, :3, :3]
    A = posed.frames @ np.swapaxes(R, 1, 2)  # (p, b, 3, 3) world rotations from rest
    t = posed.heads - np.einsum("pbij,bj->pbi", A, skeleton.matrix_local[:, :3, 3])
    blocks = np.concatenate([np.swapaxes(A, 2, 3), t[:, :, None, :]], axis=2)[
        :, num.edge_bone
    ]  # (p, m, 4, 3)
    for i, block in enumerate(blocks):
        write_dmat(f"{prefix}-pose-{i:04d}.dmat", block.reshape(4 * m, 3))


def _weight_triangles(skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    w = skeleton.weights
    used = np.flatnonzero(w > 0)
    s = np.sqrt(2.0 * w[used])
    corner = skeleton.rest_tails[used]
    V = np.stack([corner, corner + s[:, None] * [1.0, 0.0, 0.0], corner + s[:, None] * [0.0, 1.0, 0.0]], 1)
    F = np.arange(3 * len(used)).reshape(-1, 3)
    W = np.zeros((3 * len(used), skeleton.n_bones))
    W[np.arange(3 * len(used)), np.repeat(used, 3)] = 1.0
    return V.reshape(-1, 3), F, W


# ================================================================== reductions


@dataclass(frozen=True)
class ReducerSetup:
    """Their reducer's output (``ExportSetup``): what :func:`write_reduction` writes and
    :func:`read_reduction` reads.

    Attributes
    ----------
    localcos : (N, 3, 3) ndarray
        Per node ``h``: the rest frame (their axes, ``x`` along the bone) of the link after the joint on the
        edge leaving ``h``; zero where there is none.
    restpose : (N, 3, 3) ndarray
        Per node: that joint's rest rotation in world coordinates.
    splitgeo : (k, 5) ndarray
        Device links ``[h_parent, h_child, roll, pitch, yaw]`` (see the module docstring).
    """

    localcos: np.ndarray
    restpose: np.ndarray
    splitgeo: np.ndarray

    @property
    def joints(self) -> np.ndarray:
        """(j,) the nodes whose edge carries a joint (non-zero ``localcos``), in increasing order."""
        return np.flatnonzero(np.abs(self.localcos).max(axis=(1, 2)) > 0)

    def rest_readings(self) -> dict[int, np.ndarray]:
        """Per jointed node (:attr:`joints`), the joint's rest rotation as our joint reading, a (4,)
        quaternion (outlet frame in inlet frame, our axes): ``Fᵀ · restpose · F`` with ``F`` the link frame
        in our axes."""
        F = self.localcos @ THEIR_AXES.T  # their axes (x, y, z) → ours: our (x, y, z) = their (z, x, y)
        local = np.swapaxes(F, 1, 2) @ self.restpose @ F
        return {int(h): rot.from_matrix(local[h]) for h in self.joints}


def write_reduction(prefix, reduction: Reduction, skeleton: Skeleton | None = None) -> ReducerSetup:
    """Write ``prefix-localcos.dmat``, ``prefix-restpose.dmat`` and ``prefix-splitgeo.dmat`` for our
    ``reduction``, numbered as the rig in ``prefix.tgf`` (bones matched to its edges by position; bone or
    node mode from ``prefix-weights.dmat``'s columns when it exists). Without ``prefix.tgf``, writes it too,
    numbered as :func:`write_rig` numbers.

    Parameters
    ----------
    prefix : str or os.PathLike
    reduction : Reduction
    skeleton : Skeleton, optional
        The skeleton the reduction was computed for (default ``reduction.skeleton``).

    Returns
    -------
    ReducerSetup
        What was written.

    Raises
    ------
    RigError
        If ``skeleton`` is not the reduction's, a bone of the reduction has no edge in ``prefix.tgf``, or a
        file cannot be read or written.
    """
    prefix = _prefix(prefix)
    sk = reduction.skeleton if skeleton is None else skeleton
    if sk is not reduction.skeleton and (
        sk.n_bones != reduction.skeleton.n_bones
        or not np.allclose(sk.matrix_local, reduction.skeleton.matrix_local, atol=COINCIDE * sk.size)
    ):
        raise RigError("the skeleton is not the one the reduction was computed for")
    tgf_path = Path(f"{prefix}.tgf")
    if tgf_path.exists():
        bones = _bones(read_tgf(tgf_path), dmat_columns(Path(f"{prefix}-weights.dmat")), str(tgf_path))
        key, root, n_nodes, order = _match(sk, bones, str(tgf_path))
    else:
        num = _numbering(sk)
        write_tgf(tgf_path, num.tgf)
        key = num.tgf.edges[num.bone_edge, 0]
        root, n_nodes, order = 0, len(num.tgf.nodes), num.bone_edge
    device = reduction.device
    M = sk.matrix_local[:, :3, :3]
    localcos = np.zeros((n_nodes, 3, 3))
    restpose = np.zeros((n_nodes, 3, 3))
    jointed = sorted(device.joints, key=lambda pid: order[reduction.bones[pid]])
    for pid in jointed:
        b = reduction.bones[pid]
        h = key[b]
        localcos[h] = M[b] @ THEIR_AXES  # columns: our y, z, x = their x, y, z
        restpose[h] = M[b] @ rot.to_matrix(reduction.rest[pid]) @ M[b].T

    def piece_key(pid: int) -> int:
        return root if pid == 0 else int(key[reduction.bones[pid]])

    rows = []
    for sid in device.splitters:
        s = device[sid]
        in_slot = {c.slot: c.id for c in device.children(sid)}
        S = THEIR_AXES.T @ rot.to_matrix(s.splitter.slots) @ THEIR_AXES
        roll = np.arctan2(S[:, 2, 1], S[:, 2, 2])
        pitch = np.arctan2(-S[:, 2, 0], np.hypot(S[:, 2, 1], S[:, 2, 2]))
        yaw = np.arctan2(S[:, 1, 0], S[:, 0, 0])
        for j in range(s.valence):
            child = piece_key(in_slot[j]) if j in in_slot else -1
            rows.append([piece_key(s.parent), child, roll[j], pitch[j], yaw[j]])
    for pid in device.joints:
        parent = device[pid].parent
        if parent == 0 or device[parent].kind == "joint":
            rows.append([piece_key(parent), piece_key(pid), 0.0, 0.0, 0.0])
    setup = ReducerSetup(localcos, restpose, np.array(rows, dtype=np.float64).reshape(-1, 5))
    write_dmat(f"{prefix}-localcos.dmat", localcos.reshape(-1, 3))
    write_dmat(f"{prefix}-restpose.dmat", restpose.reshape(-1, 3))
    write_dmat(f"{prefix}-splitgeo.dmat", setup.splitgeo)
    return setup


def _match(sk: Skeleton, bones: _Bones, where: str) -> tuple[np.ndarray, int, int, np.ndarray]:
    """Per bone of ``sk``: its edge's head node (the key) and the edge's index; the root node; the node
    count."""
    heads, tails = sk.matrix_local[:, :3, 3], sk.rest_tails
    theirs_h, theirs_t = bones.nodes[bones.head], bones.nodes[bones.tail]
    d = np.linalg.norm(heads[:, None] - theirs_h[None], axis=2) + np.linalg.norm(
        tails[:, None] - theirs_t[None], axis=2
    )
    best = np.argmin(d, axis=1)
    bad = np.flatnonzero(d[np.arange(sk.n_bones), best] > 2 * COINCIDE * sk.size)
    if bad.size:
        raise RigError(f"{where}: bones {sk._list(bad)} match no edge of the file", bones=bad)
    return bones.head[best], bones.root, len(bones.nodes), bones.edge[best]


def read_reduction(prefix) -> ReducerSetup:
    """Their reducer's output files (or ours, :func:`write_reduction`) as a :class:`ReducerSetup`.

    Raises
    ------
    RigError
        For a missing or malformed file or mismatched shapes, naming the file.
    """
    prefix = _prefix(prefix)
    out = []
    for what in ("localcos", "restpose"):
        path = f"{prefix}-{what}.dmat"
        A = read_dmat(path)
        if A.ndim != 2 or A.shape[1] != 3 or A.shape[0] % 3:
            raise RigError(f"{path}: expected 3 columns and 3 rows per node, got {A.shape}")
        out.append(A.reshape(-1, 3, 3))
    if out[0].shape != out[1].shape:
        raise RigError(
            f"{prefix}-localcos.dmat and {prefix}-restpose.dmat disagree on the node count: "
            f"{len(out[0])} and {len(out[1])}"
        )
    path = f"{prefix}-splitgeo.dmat"
    S = read_dmat(path)
    if S.shape[1:] != (5,) and S.size:
        raise RigError(f"{path}: expected 5 columns, got {S.shape}")
    return ReducerSetup(out[0], out[1], S.reshape(-1, 5))
