"""A minimal rig description for the device: bones, rest frames, lengths, node weights, sample poses.

Conventions are Blender's, so that an armature (or a :class:`solver.Rig`, which uses the same ones)
fills a :class:`Skeleton` field by field:

==========================  ====================================================================
``Skeleton``                Blender / ``solver.Rig``
==========================  ====================================================================
``names``                   ``armature.data.bones[i].name`` / ``rig.names``
``parents``                 index of ``bone.parent`` (-1 for none) / ``rig.parents``
``matrix_local`` (b, 4, 4)  ``bone.matrix_local`` (armature space; head at the translation, y axis
                            from head to tail) / ``rig.matrix_local``
``lengths`` (b,)            ``bone.length`` / ``rig.lengths``
poses (p, b, 4)             ``pose_bone.rotation_quaternion`` per sample pose (Euler bones:
                            ``rotation_euler.to_quaternion()``; ``solver.Rig``:
                            ``rotations.from_matrix(rig.basis(theta)[:, :3, :3])``)
==========================  ====================================================================

Bones are listed parents first (``parents[b] < b``); several roots are allowed. A pose is the local
rotation of every bone in its own rest frame (Blender's ``matrix_basis`` rotation, quaternions
``(w, x, y, z)``), so the posed frame of bone ``b`` is
``F[b] = F[parent] · R_rest[parent]ᵀ R_rest[b] · pose[b]`` with heads carried along rigidly. Root
translations are ignored: the device senses rotations only, and the character's global placement is
controlled elsewhere (§6).

The rig's **nodes** (Eq. 1) are the bone tails, one per bone. Their **weights** are the surface area each
bone controls directly (:func:`area_weights`, from a skinned mesh); without a skin the default proxy is
the bone's length — a limb's skin is roughly a tube of even radius along its bones, so its area grows
with length.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from geodesics.arrays import readonly

from . import rotations as rot
from .errors import RigError

__all__ = ["Posed", "Skeleton", "area_weights"]


@dataclass(frozen=True)
class Posed:
    """Forward kinematics of a batch of poses.

    Attributes
    ----------
    frames : (..., b, 3, 3)
        Posed bone frames (rotation part) in armature space.
    heads, tails : (..., b, 3)
        Posed head and tail positions; the tails are the rig's nodes.
    """

    frames: np.ndarray
    heads: np.ndarray
    tails: np.ndarray


class Skeleton:
    """A bone tree with rest frames and per-node weights.

    Parameters
    ----------
    names : sequence of str
        Unique bone names, parents first.
    parents : (b,) array_like of int
        Parent of each bone, -1 for a root; ``parents[b] < b``.
    matrix_local : (b, 4, 4) array_like
        Rest matrices in armature space (rigid, no scale).
    lengths : (b,) array_like
        Head-to-tail lengths, positive.
    weights : (b,) array_like, optional
        Node weights (area each bone controls directly); default ``lengths``.

    Raises
    ------
    RigError
        Naming the offending bones.
    """

    def __init__(self, names: Sequence[str], parents, matrix_local, lengths, weights=None):
        self.names: tuple[str, ...] = tuple(str(n) for n in names)
        b = len(self.names)
        if b == 0:
            raise RigError("a skeleton needs at least one bone")
        if len(set(self.names)) != b:
            dup = sorted({n for n in self.names if self.names.count(n) > 1})
            raise RigError(f"bone names must be unique; repeated: {', '.join(dup)}")
        P = np.asarray(parents, dtype=np.int64).reshape(-1)
        if P.size != b:
            raise RigError(f"got {b} bone names but {P.size} parents")
        bad = np.flatnonzero((np.arange(b) <= P) | (P < -1))
        if bad.size:
            raise RigError(
                f"bones {self._list(bad)} must have a parent listed before them (or -1 for a root)", bones=bad
            )
        M = np.asarray(matrix_local, dtype=np.float64)
        if M.shape != (b, 4, 4):
            raise RigError(f"matrix_local must have shape ({b}, 4, 4), got {M.shape}")
        R = M[:, :3, :3]
        with np.errstate(invalid="ignore"):
            off = np.abs(np.swapaxes(R, 1, 2) @ R - np.eye(3)).max(axis=(1, 2))
            bad = np.flatnonzero(~(off < 1e-6) | ~(np.linalg.det(R) > 0) | ~np.isfinite(M).all(axis=(1, 2)))
        if bad.size:
            raise RigError(f"rest matrices of bones {self._list(bad)} are not rigid and finite", bones=bad)
        L = np.asarray(lengths, dtype=np.float64).reshape(-1)
        if L.size != b:
            raise RigError(f"got {b} bones but {L.size} lengths")
        bad = np.flatnonzero(~(L > 0) | ~np.isfinite(L))
        if bad.size:
            raise RigError(f"bones {self._list(bad)} have a zero, negative or non-finite length", bones=bad)
        W = L.copy() if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
        if W.size != b:
            raise RigError(f"got {b} bones but {W.size} weights")
        bad = np.flatnonzero(~(W >= 0) | ~np.isfinite(W))
        if bad.size:
            raise RigError(f"bones {self._list(bad)} have negative or non-finite weights", bones=bad)
        if not W.sum() > 0:
            raise RigError("at least one node weight must be positive")
        self.parents = readonly(P)
        self.matrix_local = readonly(M.copy())
        self.lengths = readonly(L.copy())
        self.weights = readonly(W.copy())

    def _list(self, ids) -> str:
        ids = np.unique(np.asarray(ids))
        shown = ", ".join(f"{int(i)} {self.names[i]!r}" for i in ids[:6])
        return shown if ids.size <= 6 else f"{shown}, … ({ids.size} in all)"

    @classmethod
    def from_heads_tails(cls, names, parents, heads, tails, z_axes=None, weights=None) -> Skeleton:
        """A skeleton from rest heads and tails (b, 3), with optional z axes (b, 3) for the roll.

        Without ``z_axes`` each bone's z axis is the one of the rest of its parent turned onto the bone
        by the smallest rotation (the world z axis for roots, or world -y when the bone is vertical).
        """
        H = np.asarray(heads, dtype=np.float64)
        T = np.asarray(tails, dtype=np.float64)
        n = len(names)
        if H.shape != (n, 3) or T.shape != (n, 3):
            raise RigError(f"heads and tails must have shape ({n}, 3), got {H.shape}, {T.shape}")
        d = T - H
        lengths = np.linalg.norm(d, axis=1)
        bad = np.flatnonzero(~(lengths > 0))
        if bad.size:
            raise RigError(f"bones {bad.tolist()} have head == tail", bones=bad)
        y = d / lengths[:, None]
        parents = np.asarray(parents, dtype=np.int64).reshape(-1)
        M = np.zeros((n, 4, 4))
        M[:, 3, 3] = 1.0
        M[:, :3, 3] = H
        for b in range(n):
            if z_axes is not None:
                z = np.asarray(z_axes, dtype=np.float64)[b]
            elif 0 <= parents[b] < b:
                pr = M[parents[b], :3, :3]
                q = _shortest_arc(pr[:, 1], y[b])
                z = rot.rotate(q, pr[:, 2])
            else:
                z = np.array([0.0, 0.0, 1.0]) if abs(y[b, 2]) < 0.9 else np.array([0.0, -1.0, 0.0])
            z = z - np.dot(z, y[b]) * y[b]
            if not np.linalg.norm(z) > 1e-9:
                raise RigError(f"bone {b} {names[b]!r} has a z axis parallel to the bone", bones=[b])
            z /= np.linalg.norm(z)
            M[b, :3, 0], M[b, :3, 1], M[b, :3, 2] = np.cross(y[b], z), y[b], z
        return cls(names, parents, M, lengths, weights)

    # ------------------------------------------------------------------ structure

    @property
    def n_bones(self) -> int:
        return len(self.names)

    def bone_index(self, bone: int | str) -> int:
        """Index of a bone given by name or index."""
        if isinstance(bone, str):
            try:
                return self.names.index(bone)
            except ValueError:
                raise RigError(f"the skeleton has no bone called {bone!r}") from None
        b = int(bone)
        if not 0 <= b < self.n_bones:
            raise RigError(f"bone index {b} is outside 0..{self.n_bones - 1}")
        return b

    @cached_property
    def roots(self) -> np.ndarray:
        """(r,) the bones without a parent, in increasing order (read-only)."""
        return readonly(np.flatnonzero(self.parents < 0))

    @cached_property
    def children(self) -> tuple[tuple[int, ...], ...]:
        """Children of every bone, in index order."""
        out: list[list[int]] = [[] for _ in range(self.n_bones)]
        for b, p in enumerate(self.parents):
            if p >= 0:
                out[p].append(b)
        return tuple(tuple(c) for c in out)

    @cached_property
    def subtree(self) -> np.ndarray:
        """(b, b) bool: ``subtree[a, c]`` when bone c is a or one of its descendants."""
        S = np.eye(self.n_bones, dtype=bool)
        for b in range(self.n_bones - 1, -1, -1):
            p = self.parents[b]
            if p >= 0:
                S[p] |= S[b]
        return readonly(S)

    @cached_property
    def levels(self) -> tuple[np.ndarray, ...]:
        """Bones grouped by depth: one read-only int array of each depth's bones, in increasing order,
        roots first."""
        depth = np.zeros(self.n_bones, np.int64)
        for b, p in enumerate(self.parents):
            depth[b] = 0 if p < 0 else depth[p] + 1
        return tuple(readonly(np.flatnonzero(depth == d)) for d in range(depth.max() + 1))

    @cached_property
    def rest_offsets(self) -> tuple[np.ndarray, np.ndarray]:
        """``(R, t)``: each bone's rest rotation (b, 3, 3) and head (b, 3) in its parent's rest frame
        (in armature space for roots)."""
        M = self.matrix_local
        R = M[:, :3, :3].copy()
        t = M[:, :3, 3].copy()
        has = self.parents >= 0
        par = M[self.parents[has]]
        R[has] = np.swapaxes(par[:, :3, :3], 1, 2) @ M[has, :3, :3]
        t[has] = np.einsum("bji,bj->bi", par[:, :3, :3], M[has, :3, 3] - par[:, :3, 3])
        return readonly(R), readonly(t)

    @cached_property
    def size(self) -> float:
        """Characteristic length: the diagonal of the rest nodes' and heads' bounding box."""
        X = np.concatenate([self.matrix_local[:, :3, 3], self.rest_tails])
        return float(max(np.linalg.norm(X.max(0) - X.min(0)), self.lengths.max()))

    @cached_property
    def rest_tails(self) -> np.ndarray:
        """(b, 3) rest tail positions."""
        return readonly(self.matrix_local[:, :3, 3] + self.lengths[:, None] * self.matrix_local[:, :3, 1])

    # ------------------------------------------------------------------ poses

    def check_poses(self, poses, what: str = "poses") -> np.ndarray:
        """(..., b, 4) unit quaternions (normalized) from pose input ``poses`` (..., b, 4), or a RigError
        naming the problem."""
        Q = np.asarray(poses, dtype=np.float64)
        if Q.shape[-2:] != (self.n_bones, 4):
            raise RigError(f"{what} must have shape (..., {self.n_bones}, 4), got {Q.shape}")
        norm = np.linalg.norm(Q, axis=-1)
        bad = np.flatnonzero(np.any(~(norm > 1e-9) | ~np.isfinite(norm), axis=tuple(range(Q.ndim - 2))))
        if bad.size:
            raise RigError(f"{what}: bones {self._list(bad)} have zero or non-finite quaternions", bones=bad)
        return Q / norm[..., None]

    def forward(self, poses) -> Posed:
        """Forward kinematics of local rotations: frames (..., b, 3, 3), heads and tails (..., b, 3).

        Parameters
        ----------
        poses : (..., b, 4) or (..., b, 3, 3) array_like
            Local rotations as quaternions or matrices.
        """
        Q = np.asarray(poses, dtype=np.float64)
        local = rot.to_matrix(self.check_poses(Q)) if Q.shape[-1] == 4 else Q
        return self.forward_matrices(local)

    def forward_matrices(self, local: np.ndarray) -> Posed:
        """Forward kinematics of local rotation matrices ``local`` (..., b, 3, 3): frames (..., b, 3, 3),
        heads and tails (..., b, 3)."""
        R0, t0 = self.rest_offsets
        shape = local.shape[:-3]
        F = np.empty((*shape, self.n_bones, 3, 3))
        H = np.empty((*shape, self.n_bones, 3))
        for level in self.levels:
            p = self.parents[level]
            if p[0] < 0:
                F[..., level, :, :] = R0[level] @ local[..., level, :, :]
                H[..., level, :] = t0[level]
            else:
                Fp = F[..., p, :, :]
                F[..., level, :, :] = Fp @ (R0[level] @ local[..., level, :, :])
                H[..., level, :] = H[..., p, :] + np.einsum("...ij,...j->...i", Fp, t0[level])
        T = H + self.lengths[:, None] * F[..., :, 1]
        return Posed(F, H, T)


def _shortest_arc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Quaternion of the smallest rotation taking unit vector a to unit vector b."""
    c = np.cross(a, b)
    d = float(np.dot(a, b))
    if d < -1.0 + 1e-12:
        axis = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(a, [0.0, 1.0, 0.0])
        return rot.from_axis_angle(axis / np.linalg.norm(axis), np.pi)
    q = np.array([1.0 + d, *c])
    return q / np.linalg.norm(q)


def area_weights(vertices, faces, skin_weights) -> np.ndarray:
    """Surface area each bone controls directly: per bone, Σ over faces of area × the face's mean skin
    weight for that bone (skin weights normalized per vertex), so every patch of skin counts once.

    Parameters
    ----------
    vertices : (n, 3) array_like
    faces : (f, 3) array_like of int
    skin_weights : (n, b) array_like
        Per-vertex bone weights (Blender's vertex groups).

    Returns
    -------
    (b,)
    """
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    W = np.asarray(skin_weights, dtype=np.float64)
    if V.ndim != 2 or V.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 3 or W.ndim != 2 or len(W) != len(V):
        raise RigError(
            f"need vertices (n, 3), faces (f, 3) and skin weights (n, b); got {V.shape}, {F.shape}, {W.shape}"
        )
    if F.size and (F.min() < 0 or F.max() >= len(V)):
        raise RigError(f"faces index vertices outside 0..{len(V) - 1}")
    total = W.sum(axis=1, keepdims=True)
    W = np.divide(W, total, out=np.zeros_like(W), where=total > 0)
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    return area @ W[F].mean(axis=1)
