"""Linear blend skinning as Blender's Armature modifier does it, with analytic derivatives.

Conventions:

* Weights are a sparse ``(n_vertices, n_bones)`` matrix (Blender's vertex groups, one column per deform
  bone). The Armature modifier divides each vertex's weights by their sum (Preserve Volume off), so a
  :class:`SkinnedMesh` takes weights whose rows sum to one (:func:`normalize_vertex_groups` turns raw
  vertex-group weights into that); a row of zeros is a vertex no bone moves, which Blender leaves in
  place, and so does this module.
* The posed position of vertex ``v`` is ``sum_b w[v, b] (pose[b] @ matrix_local[b]^-1) @ rest[v]``, all
  in armature space (see :mod:`solver.rig`).
* A surface point ``(face, bary)`` of the rest mesh is posed with its face: its position is the
  barycentric combination of the posed corners, its normal the unit normal of the posed triangle
  ``(p1 - p0) x (p2 - p0)`` (zero for a triangle posed into a degenerate one).
* Derivatives are with respect to the rig's DOF vector θ (see :class:`solver.rig.Rig`). A rotation DOF
  turns every point downstream of its bone about the DOF's axis ``ω`` through the bone's head ``o``:
  ``d/dθ (S_b x) = ω x (S_b x - o)``, blended with the skin weights of the bone's subtree. Forward
  Jacobians (:meth:`SkinnedMesh.point_jacobian`) cost ``O(points x DOFs)``; the objective's gradient
  uses the reverse (adjoint) form, which costs ``O(points + bones)``.
"""

from __future__ import annotations

from functools import cached_property

import numpy as np
from scipy import sparse

from geodesics import SurfacePoints, TriMesh
from geodesics.errors import MeshError

from ..errors import SolverError, describe_ids
from .control_rig import ControlRig
from .kinematics import Kinematics, Rig, cross
from .protocol import RigLike

#: Row sums of normalized weights may miss one by this much.
WEIGHT_TOLERANCE = 1e-6


def normalize_vertex_groups(weights) -> sparse.csr_matrix:
    """Blender's per-vertex normalization of raw vertex-group weights.

    Parameters
    ----------
    weights : (n, b) array_like or sparse matrix
        Non-negative raw weights (vertex group ``b`` of deform bone ``b``).

    Returns
    -------
    scipy.sparse.csr_matrix
        Each nonzero row divided by its sum; rows that sum to zero stay zero (unmoved vertices).
    """
    W = _as_csr(weights)
    _check_nonnegative(W)
    total = np.asarray(W.sum(axis=1)).ravel()
    scale = np.divide(1.0, total, out=np.zeros_like(total), where=total > 0)
    return sparse.csr_matrix(sparse.diags(scale) @ W)


def _as_csr(weights) -> sparse.csr_matrix:
    W = sparse.csr_matrix(weights, dtype=np.float64) if sparse.issparse(weights) else None
    if W is None:
        dense = np.asarray(weights, dtype=np.float64)
        if dense.ndim != 2:
            raise SolverError(f"skin weights must be a 2D (vertices, bones) matrix, got shape {dense.shape}")
        W = sparse.csr_matrix(dense)
    W.sum_duplicates()
    W.eliminate_zeros()
    return W


def _check_nonnegative(W: sparse.csr_matrix) -> None:
    rows = np.repeat(np.arange(W.shape[0]), np.diff(W.indptr))
    bad = ~np.isfinite(W.data)
    if np.any(bad):
        raise SolverError(
            f"skin weights of vertices {describe_ids(rows[bad])} are NaN or infinite", vertices=rows[bad]
        )
    bad = W.data < 0
    if np.any(bad):
        raise SolverError(
            f"skin weights of vertices {describe_ids(rows[bad])} are negative (e.g. vertex "
            f"{int(rows[bad][0])}, bone {int(W.indices[bad][0])}: {float(W.data[bad][0])!r})",
            vertices=rows[bad],
            bones=W.indices[bad],
        )


class SkinnedMesh:
    """A rest mesh bound to a rig by sparse linear-blend-skinning weights.

    Parameters
    ----------
    mesh : TriMesh
        The rest mesh, in armature space.
    rig : Rig or ControlRig
        The bones that deform it: a plain :class:`~solver.rig.Rig`, or a production rig's hand posed
        through its controls (:class:`~solver.rig.control_rig.ControlRig`, whose B-Bones deform by segments).
    weights : (n_vertices, n_deform_bones) array_like or scipy sparse matrix
        Non-negative, each row summing to one (or all zero: a vertex no bone moves); one column per
        ``rig.deform_bones``.

    Raises
    ------
    SolverError
        For a shape mismatch, NaN, negative or unnormalized weights (naming the vertices).
    """

    def __init__(self, mesh: TriMesh, rig: RigLike, weights):
        if not isinstance(mesh, TriMesh):
            raise SolverError(f"mesh must be a geodesics.TriMesh, got {type(mesh).__name__}")
        if not isinstance(rig, (Rig, ControlRig)):
            raise SolverError(f"rig must be a solver.Rig or ControlRig, got {type(rig).__name__}")
        W = _as_csr(weights)
        if W.shape != (mesh.n_vertices, len(rig.deform_bones)):
            raise SolverError(
                f"skin weights must have shape (n_vertices, n_bones) = ({mesh.n_vertices}, "
                f"{len(rig.deform_bones)}), got {W.shape}"
            )
        _check_nonnegative(W)
        total = np.asarray(W.sum(axis=1)).ravel()
        bad = np.flatnonzero((total != 0) & (np.abs(total - 1) > WEIGHT_TOLERANCE))
        if bad.size:
            raise SolverError(
                f"skin weights of vertices {describe_ids(bad)} do not sum to one (e.g. vertex "
                f"{int(bad[0])}: {float(total[bad[0]])}); normalize them with normalize_vertex_groups",
                vertices=bad,
            )
        self.mesh = mesh
        self.rig = rig
        self.weights = normalize_vertex_groups(W)
        #: (n_vertices, s) the weights per deformer (a B-Bone's split between its segments).
        self.deformer_weights = rig.segment_weights(self.weights, mesh.vertices)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.mesh!r}, {self.rig.n_bones} bones, {self.rig.n_dofs} DOFs)"

    @cached_property
    def size(self) -> float:
        """The rest mesh's bounding-box diagonal: the manipulator's characteristic size."""
        return self.mesh.bounding_diagonal

    @cached_property
    def length(self) -> float:
        """The manipulator's length, which scales the retargeting's translation thresholds: :attr:`size`
        (a procedural :class:`~solver.hands.Hand` has its wrist-to-fingertip length instead)."""
        return self.size

    # ------------------------------------------------------------------ posing

    def posed_vertices(self, theta) -> np.ndarray:
        """(n, 3) posed vertex positions at pose θ (d,)."""
        return self._all_vertices.positions(self.rig.kinematics(theta, derivatives=False))

    @cached_property
    def _all_vertices(self) -> VertexSkin:
        return VertexSkin(self)

    def posed_points(self, theta, points: SurfacePoints) -> tuple[np.ndarray, np.ndarray]:
        """Posed positions (k, 3) and unit normals (k, 3) of surface points (k) of the rest mesh at pose
        θ (d,)."""
        skin = self.point_skin([points])
        p, n, _ = skin.sets[0].geometry(
            skin.vertices.positions(self.rig.kinematics(theta, derivatives=False))
        )
        return p, n

    def vertex_jacobian(self, theta, vertex_ids=None) -> tuple[np.ndarray, np.ndarray]:
        """Posed positions (m, 3) of vertices ``vertex_ids`` (m,) (default: all) and their Jacobians
        (m, 3, d), at pose θ (d,)."""
        ids = None if vertex_ids is None else self._check_vertex_ids(vertex_ids)
        skin = self.vertex_skin(ids)
        kin = self.rig.kinematics(theta)
        return skin.positions(kin), skin.jacobian(kin)

    def point_jacobian(
        self, theta, points: SurfacePoints
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Positions (k, 3), normals (k, 3) and their Jacobians (k, 3, d), (k, 3, d) at pose θ (d,)."""
        skin = self.point_skin([points])
        kin = self.rig.kinematics(theta)
        pts = skin.sets[0]
        p, n, aux = pts.geometry(skin.vertices.positions(kin))
        dp, dn = pts.jacobian(n, aux, skin.vertices.jacobian(kin, pts.rows))
        return p, n, dp, dn

    # ------------------------------------------------------------------ evaluators for solvers

    def vertex_skin(self, vertex_ids=None) -> VertexSkin:
        """A :class:`VertexSkin` posing the given vertices (default: all)."""
        return VertexSkin(self, vertex_ids)

    def point_skin(self, point_sets, extra_vertices=None) -> PointSkin:
        """A :class:`PointSkin` posing several sets of surface points (and optionally raw vertices)."""
        return PointSkin(self, point_sets, extra_vertices)

    def _check_vertex_ids(self, vertex_ids) -> np.ndarray:
        ids = np.asarray(vertex_ids, dtype=np.int64).reshape(-1)
        bad = np.flatnonzero((ids < 0) | (ids >= self.mesh.n_vertices))
        if bad.size:
            raise SolverError(
                f"vertex indices {describe_ids(ids[bad])} are out of range 0..{self.mesh.n_vertices - 1}"
            )
        return ids


class VertexSkin:
    """Posed positions of a fixed subset of vertices, their Jacobians and vector-Jacobian products.

    Parameters
    ----------
    skin : SkinnedMesh
    vertex_ids : (m,) array_like of int, optional
        Which vertices (default: all, in order).
    """

    def __init__(self, skin: SkinnedMesh, vertex_ids=None):
        ids = np.arange(skin.mesh.n_vertices) if vertex_ids is None else np.asarray(vertex_ids, np.int64)
        self.rig = skin.rig
        self.vertex_ids = ids
        self.rest = skin.mesh.vertices[ids]
        self.weights = sparse.csr_matrix(skin.deformer_weights[ids])
        self._weights_t = sparse.csr_matrix(self.weights.T)
        self._static = np.flatnonzero(np.asarray(self.weights.sum(axis=1)).ravel() == 0)  # no bone moves them

    def __len__(self) -> int:
        return len(self.vertex_ids)

    def positions(self, kin: Kinematics) -> np.ndarray:
        """(m, 3) posed positions."""
        M = (self.weights @ kin.skinning.reshape(-1, 12)).reshape(-1, 3, 4)
        X = np.einsum("vij,vj->vi", M[:, :, :3], self.rest) + M[:, :, 3]
        X[self._static] = self.rest[self._static]
        return X

    def jacobian(self, kin, rows=None) -> np.ndarray:
        """(m, 3, d) derivatives of the posed positions with respect to θ, or (r, 3, d) of the rows ``rows``
        (r,) of this skin's vertices."""
        if rows is None:
            return kin.jacobian(self.weights.toarray(), self.rest)
        return kin.jacobian(self.weights[rows].toarray(), self.rest[rows])

    def vjp(self, kin, adjoint: np.ndarray) -> np.ndarray:
        """(d,) ``sum_v adjoint[v] . dposition[v]/dθ`` for an adjoint (m, 3), without the Jacobian."""
        return kin.pullback(self.deformer_sums(adjoint))

    def deformer_sums(self, adjoint: np.ndarray) -> np.ndarray:
        """(s, 3, 4) per-deformer sums ``Σ_v w[v, s] adjoint[v] [rest[v]; 1]^T`` of an adjoint (m, 3): the
        gradient, with respect to each skinning matrix, of a function of the posed positions."""
        G = np.empty((self.weights.shape[1], 3, 4))
        G[:, :, 3] = self._weights_t @ adjoint
        for j in range(3):
            G[:, :, j] = self._weights_t @ (self.rest[:, j, None] * adjoint)
        return G


class PointSet:
    """One set of k surface points of a :class:`PointSkin`: ``corners`` (k, 3) index its vertices."""

    def __init__(self, corners: np.ndarray, bary: np.ndarray, n_vertices: int):
        self.corners = corners
        self.bary = bary
        k = len(bary)
        # One sparse (3k, m) operator maps vertex positions to the points' positions, first edges
        # (p1 - p0) and second edges (p2 - p0); its transpose gathers their gradients per vertex.
        rows = np.repeat(np.arange(3 * k), 3)
        cols = np.tile(corners, (3, 1)).ravel()
        values = np.concatenate([bary, np.tile([-1.0, 1.0, 0.0], (k, 1)), np.tile([-1.0, 0.0, 1.0], (k, 1))])
        self._stack = sparse.csr_matrix((values.ravel(), (rows, cols)), shape=(3 * k, n_vertices))
        self._stack_t = sparse.csr_matrix(self._stack.T)
        #: (r,) the vertices (rows of the skin's vertex array) the points lie on, in increasing order.
        self.rows = np.unique(corners)
        self._stack_rows = sparse.csr_matrix(self._stack[:, self.rows])

    def __len__(self) -> int:
        return len(self.bary)

    def geometry(self, V: np.ndarray):
        """Positions (k, 3), unit normals (k, 3) and the triangle data the adjoint needs, from the posed
        vertices V (m, 3)."""
        k = len(self.bary)
        Y = self._stack @ V
        p, e1, e2 = Y[:k], Y[k : 2 * k], Y[2 * k :]
        u = cross(e1, e2)
        norm = np.sqrt(np.einsum("ki,ki->k", u, u))
        inv = 1.0 / np.where(norm > 0, norm, np.inf)  # a degenerate posed triangle has no normal
        return p, u * inv[:, None], (inv, e1, e2)

    def jacobian(self, n: np.ndarray, aux, J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The derivatives (k, 3, d) of the positions and of the unit normals (``n``, ``aux`` from
        :meth:`geometry`), from the Jacobians J (r, 3, d) of the vertices :attr:`rows`."""
        k, d = len(self.bary), J.shape[2]
        Y = (self._stack_rows @ J.reshape(len(J), 3 * d)).reshape(3 * k, 3, d)
        dp, de1, de2 = Y[:k], Y[k : 2 * k], Y[2 * k :]
        inv, e1, e2 = aux
        du = _cross_columns(de1, e2) - _cross_columns(de2, e1)  # d(e1 × e2) = de1 × e2 + e1 × de2
        dn = (du - n[:, :, None] * np.einsum("ki,kid->kd", n, du)[:, None, :]) * inv[:, None, None]
        return dp, dn

    def adjoint(self, n: np.ndarray, aux, grad_p, grad_n) -> np.ndarray:
        """(m, 3) per-vertex adjoint of ``grad_p . dp + grad_n . dn`` (either gradient may be None)."""
        k = len(self.bary)
        G = np.zeros((3 * k, 3))
        if grad_p is not None:
            G[:k] = grad_p
        if grad_n is not None:
            inv, e1, e2 = aux
            gu = (grad_n - n * np.einsum("ki,ki->k", n, grad_n)[:, None]) * inv[:, None]
            G[k : 2 * k] = cross(e2, gu)
            G[2 * k :] = cross(gu, e1)
        return self._stack_t @ G


def _cross_columns(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(k, 3, d) ``A[:, :, j] × b`` for each column j of A (k, 3, d) and vectors b (k, 3)."""
    out = np.empty_like(A)
    out[:, 0] = A[:, 1] * b[:, 2, None] - A[:, 2] * b[:, 1, None]
    out[:, 1] = A[:, 2] * b[:, 0, None] - A[:, 0] * b[:, 2, None]
    out[:, 2] = A[:, 0] * b[:, 1, None] - A[:, 1] * b[:, 0, None]
    return out


class PointSkin:
    """Poses several sets of surface points (and raw vertices) through one shared :class:`VertexSkin`.

    Parameters
    ----------
    skin : SkinnedMesh
    point_sets : sequence of SurfacePoints
        Points on ``skin.mesh``.
    extra_vertices : (s,) array_like of int, optional
        Vertices to pose as well (e.g. samples for a table penalty); their rows in the shared vertex
        array are ``extra_rows``.
    """

    def __init__(self, skin: SkinnedMesh, point_sets, extra_vertices=None):
        mesh = skin.mesh
        faces = []
        for points in point_sets:
            if not isinstance(points, SurfacePoints):
                raise SolverError(f"hand points must be geodesics.SurfacePoints, got {type(points).__name__}")
            try:
                points.validate(mesh)
            except MeshError as error:
                raise SolverError(f"hand points do not lie on the hand mesh: {error}") from None
            faces.append(mesh.faces[points.faces])
        extra = np.empty(0, np.int64) if extra_vertices is None else skin._check_vertex_ids(extra_vertices)
        used = np.concatenate([f.ravel() for f in faces] + [extra])
        ids, inverse = np.unique(used, return_inverse=True)
        self.vertices = VertexSkin(skin, ids)
        self.sets: list[PointSet] = []
        start = 0
        for points, f in zip(point_sets, faces, strict=True):
            chunk = inverse[start : start + f.size].reshape(-1, 3)
            self.sets.append(PointSet(chunk, points.bary, ids.size))
            start += f.size
        self.extra_rows = inverse[start:]
