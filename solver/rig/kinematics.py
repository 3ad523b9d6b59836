"""Armatures as Blender poses them: a tree of bones with rest matrices, a DOF vector, forward kinematics.

Conventions (Blender's, for directly posed deform bones, so that a Blender armature maps onto a
:class:`Rig` and poses come back identical):

* Every bone has a rest matrix in armature space, ``matrix_local`` (Blender's ``bone.matrix_local``,
  4x4): its translation is the bone's head, its y axis points along the bone towards the tail, its x
  and z axes carry the roll. ``lengths`` are head-to-tail distances.
* Bones are listed parents first: ``parents[0] == -1`` (the one root) and ``parents[b] < b``.
* A pose gives each bone a local transform ``basis`` (Blender's ``pose_bone.matrix_basis``): a
  translation (root only, Blender's ``location``, in the bone's rest frame) followed by a rotation. The
  posed armature-space matrix (Blender's ``pose_bone.matrix``) is
  ``pose[b] = pose[parent] @ (matrix_local[parent]^-1 @ matrix_local[b]) @ basis[b]``, and
  ``pose[root] = matrix_local[root] @ basis[root]``.
* **DOFs.** The root has six (location x, y, z, then rotation x, y, z), every other bone three
  (rotation x, y, z): ``6 + 3 (n_bones - 1)`` in all, in bone order. Rotations are **Euler angles in
  the bone's local (rest) frame**, in the bone's Blender rotation mode (``"XYZ"`` by default; see
  :mod:`solver.rotations`): the values are exactly Blender's ``pose_bone.rotation_euler`` and θ = 0
  is the rest pose. Why Euler: a joint's limits (Blender's Limit Rotation constraint, IK limits,
  locks) are then plain box bounds ``lower <= θ <= upper`` that a bounded optimizer enforces exactly,
  and animators key finger curls as single Euler channels. The parameterization is singular only
  when the middle angle reaches ±90°; with the default ``"XYZ"`` and the bone along y that is a 90°
  twist, which finger and tentacle limits keep far away. Quaternion or axis-angle bones convert
  exactly through :meth:`Rig.basis` / :meth:`Rig.theta_from_basis` and :mod:`solver.rotations`.
* Locked DOFs (Blender's ``lock_location`` / ``lock_rotation``) keep their value in every solve.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy import sparse

from geodesics.arrays import readonly

from ..errors import SolverError, describe_ids
from ..rotations import EULER_ORDERS, axis_rotation, matrix_to_euler, order_axes
from .dofs import EulerDofs

#: Rest rotations must be orthonormal to this tolerance.
ORTHONORMAL_TOLERANCE = 1e-6
#: A bone shorter than this fraction of the longest bone counts as zero-length.
MIN_RELATIVE_LENGTH = 1e-9


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross products of (k, 3) arrays (numpy's general ``cross`` is several times slower)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape), dtype=np.result_type(a, b))
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


@dataclass(frozen=True)
class Kinematics:
    """Forward kinematics of one pose of a :class:`Rig`, with what the analytic derivatives need.

    Attributes
    ----------
    rig : Rig
    matrices : (b, 4, 4)
        Posed armature-space bone matrices (Blender's ``pose_bone.matrix``).
    skinning : (b, 3, 4)
        ``(matrices @ matrix_local^-1)[:, :3]``: what each bone does to a rest-space point.
    axes : (d, 3)
        Per DOF, the unit armature-space direction a translation DOF moves along, or the axis a rotation
        DOF turns about, at this pose.
    origins : (d, 3)
        Per rotation DOF, the pivot (the posed bone head); zero for translation DOFs.
    """

    rig: Rig
    matrices: np.ndarray
    skinning: np.ndarray
    axes: np.ndarray
    origins: np.ndarray

    def pullback(self, sums: np.ndarray) -> np.ndarray:
        """(d,) ``Σ_b <dS_b/dθ, sums_b>``: the gradient of a function of the skinning matrices S (b, 3, 4)
        whose gradient with respect to them is ``sums`` (b, 3, 4).

        A rotation DOF turns bone b's downstream points about its axis ω through its pivot o, so
        ``dS_b/dθ = [ω]x (S_b - o e_4^T)`` on the DOF's subtree and the sum reduces to per-bone torques
        and forces accumulated up the tree: O(bones + DOFs).
        """
        rig = self.rig
        f = sums[:, :, 3]  # (b, 3) per-bone force
        RC = self.skinning[:, :, :3] @ sums[:, :, :3].transpose(0, 2, 1)
        tau = np.stack([RC[:, 1, 2] - RC[:, 2, 1], RC[:, 2, 0] - RC[:, 0, 2], RC[:, 0, 1] - RC[:, 1, 0]], 1)
        tau += cross(self.skinning[:, :, 3], f)
        D = rig.subtree.T.astype(np.float64)
        F, T = D @ f, D @ tau
        bone = rig.dof_bone
        moment = T[bone] - cross(self.origins, F[bone])
        moment[:3] = F[0]
        return np.einsum("di,di->d", self.axes, moment)

    def jacobian(self, weights: np.ndarray, rest: np.ndarray) -> np.ndarray:
        """(m, 3, d) derivatives of the points ``Σ_b weights[v, b] S_b [rest_v; 1]`` (weights (m, b) dense,
        rest (m, 3)) with respect to θ."""
        rig = self.rig
        D = rig.subtree.astype(np.float64)
        S = self.skinning
        # Each point as each bone poses it, weighted, then summed over each bone's subtree: Y[v, c] is the
        # part of point v that bone c's DOFs move (m, b, 3).
        posed = np.einsum("bij,vj->vbi", S[:, :, :3], rest) + S[None, :, :, 3]
        Y = ((weights[:, :, None] * posed).transpose(0, 2, 1) @ D).transpose(0, 2, 1)
        Wsub = weights @ D
        bone = rig.dof_bone
        J = np.empty((len(weights), 3, rig.n_dofs))
        J[:, :, :3] = Wsub[:, 0, None, None] * self.axes[:3].T[None]
        rot = np.flatnonzero(rig.is_rotation)
        lever = Y[:, bone[rot]] - Wsub[:, bone[rot], None] * self.origins[rot][None]
        a = self.axes[rot]
        J[:, 0, rot] = a[:, 1] * lever[:, :, 2] - a[:, 2] * lever[:, :, 1]
        J[:, 1, rot] = a[:, 2] * lever[:, :, 0] - a[:, 0] * lever[:, :, 2]
        J[:, 2, rot] = a[:, 0] * lever[:, :, 1] - a[:, 1] * lever[:, :, 0]
        return J


class Rig(EulerDofs):
    """A bone tree with rest matrices, DOF limits and locks.

    Parameters
    ----------
    names : sequence of str
        Unique bone names, parents first.
    parents : (b,) array_like of int
        Parent of each bone; -1 for bone 0 (the root) only, ``parents[i] < i`` otherwise.
    matrix_local : (b, 4, 4) array_like
        Rest matrices in armature space (Blender's ``bone.matrix_local``).
    lengths : (b,) array_like
        Bone lengths (head to tail), positive.
    lower, upper : (d,) array_like, optional
        DOF bounds; default unbounded location and ±π rotations.
    locked : (d,) array_like of bool, optional
        DOFs that solves never change.
    rotation_modes : sequence of str, optional
        Euler order of each bone (one of :data:`solver.rotations.EULER_ORDERS`), default ``"XYZ"``.

    Raises
    ------
    SolverError
        For a malformed tree (names, parents), non-rigid or non-finite rest matrices, zero-length bones,
        NaN or inverted limits; the message names the bones or DOFs.
    """

    def __init__(
        self,
        names,
        parents,
        matrix_local,
        lengths,
        lower=None,
        upper=None,
        locked=None,
        rotation_modes=None,
    ):
        self.names: tuple[str, ...] = tuple(str(n) for n in names)
        nb = len(self.names)
        if nb == 0:
            raise SolverError("a rig needs at least one bone")
        if len(set(self.names)) != nb:
            dup = sorted({n for n in self.names if self.names.count(n) > 1})
            raise SolverError(f"bone names must be unique; repeated: {', '.join(dup)}")
        self.parents = readonly(self._checked_parents(parents))
        self.matrix_local = readonly(self._checked_rest(matrix_local))
        self.lengths = readonly(self._checked_lengths(lengths))
        self.rotation_modes: tuple[str, ...] = self._checked_modes(rotation_modes)

        self._lay_out_dofs()
        nd = self.n_dofs
        lo, hi = self._checked_limits(lower, upper)
        self.lower = readonly(lo)
        self.upper = readonly(hi)
        lk = np.zeros(nd, bool) if locked is None else np.array(locked, dtype=bool).reshape(-1)
        if lk.size != nd:
            raise SolverError(f"locked needs {nd} flags (one per DOF), got {lk.size}")
        self.locked = readonly(lk)
        self._forward_constants()

    def _checked_parents(self, parents) -> np.ndarray:
        """(b,) int64 parents, each listed before its bone, bone 0 the only root."""
        nb = len(self.names)
        P = np.array(parents, dtype=np.int64).reshape(-1)
        if P.size != nb:
            raise SolverError(f"got {nb} bone names but {P.size} parents")
        bad = np.flatnonzero(P[1:] >= np.arange(1, nb)) + 1
        bad = np.union1d(bad, np.flatnonzero(P[1:] < 0) + 1)
        if P[0] != -1:
            raise SolverError(f"bone 0 ({self.names[0]!r}) must be the root (parent -1)", bones=[0])
        if bad.size:
            b = int(bad[0])
            raise SolverError(
                f"bones {self._bone_list(bad)} must have a parent listed before them (bone {b} "
                f"{self.names[b]!r} has parent {int(P[b])}); only bone 0 is a root",
                bones=bad,
            )
        return P

    def _checked_rest(self, matrix_local) -> np.ndarray:
        """(b, 4, 4) float64 rest matrices, finite and rigid."""
        nb = len(self.names)
        M = np.array(matrix_local, dtype=np.float64)
        if M.shape != (nb, 4, 4):
            raise SolverError(f"matrix_local must have shape ({nb}, 4, 4), got {M.shape}")
        bad = np.flatnonzero(~np.all(np.isfinite(M), axis=(1, 2)))
        if bad.size:
            raise SolverError(f"rest matrices of bones {self._bone_list(bad)} are not finite", bones=bad)
        R = M[:, :3, :3]
        off = np.abs(R.transpose(0, 2, 1) @ R - np.eye(3)).max(axis=(1, 2))
        row = np.abs(M[:, 3] - [0, 0, 0, 1]).max(axis=1)
        bad = np.flatnonzero(
            (off > ORTHONORMAL_TOLERANCE) | (np.linalg.det(R) <= 0) | (row > ORTHONORMAL_TOLERANCE)
        )
        if bad.size:
            raise SolverError(
                f"rest matrices of bones {self._bone_list(bad)} are not rigid (a rotation with "
                "determinant +1 and a translation; Blender's bone.matrix_local has no scale)",
                bones=bad,
            )
        return M

    def _checked_lengths(self, lengths) -> np.ndarray:
        """(b,) float64 lengths, positive and finite."""
        nb = len(self.names)
        L = np.array(lengths, dtype=np.float64).reshape(-1)
        if L.size != nb:
            raise SolverError(f"got {nb} bones but {L.size} lengths")
        longest = np.max(np.abs(L[np.isfinite(L)]), initial=0.0)
        bad = np.flatnonzero(~np.isfinite(L) | (MIN_RELATIVE_LENGTH * max(longest, 1e-300) >= L))
        if bad.size:
            raise SolverError(
                f"bones {self._bone_list(bad)} have zero, negative or non-finite length "
                f"(e.g. {self.names[bad[0]]!r}: {float(L[bad[0]])})",
                bones=bad,
            )
        return L

    def _checked_modes(self, rotation_modes) -> tuple[str, ...]:
        """One Euler order per bone (``"XYZ"`` by default)."""
        nb = len(self.names)
        modes = tuple(rotation_modes) if rotation_modes is not None else ("XYZ",) * nb
        if len(modes) != nb:
            raise SolverError(f"got {nb} bones but {len(modes)} rotation modes")
        bad = [b for b, m in enumerate(modes) if m not in EULER_ORDERS]
        if bad:
            raise SolverError(
                f"bones {self._bone_list(bad)} have rotation mode {modes[bad[0]]!r}; DOFs are Euler "
                f"angles in one of {', '.join(EULER_ORDERS)} (convert quaternions with "
                "Rig.theta_from_basis)",
                bones=bad,
            )
        return modes

    def _checked_limits(self, lower, upper) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) (d,) DOF limits: not NaN, not inverted; default unbounded location and ±π
        rotations."""
        nd = len(self.dof_bone)
        default_lo = np.where(self.is_rotation, -np.pi, -np.inf)
        lo = default_lo if lower is None else np.array(lower, dtype=np.float64).reshape(-1)
        hi = -default_lo if upper is None else np.array(upper, dtype=np.float64).reshape(-1)
        for what, a in (("lower", lo), ("upper", hi)):
            if a.size != nd:
                raise SolverError(f"{what} limits need {nd} values (one per DOF), got {a.size}")
            bad = np.flatnonzero(np.isnan(a))
            if bad.size:
                raise SolverError(
                    f"{what} limits of DOFs {self._dof_list(bad)} are NaN", dofs=bad, bones=self.dof_bone[bad]
                )
        bad = np.flatnonzero(lo > hi)
        if bad.size:
            d = int(bad[0])
            raise SolverError(
                f"limits of DOFs {self._dof_list(bad)} are inverted (lower > upper, e.g. "
                f"{self.dof_names[d]}: {float(lo[d])} > {float(hi[d])})",
                dofs=bad,
                bones=self.dof_bone[bad],
            )
        return lo, hi

    def _forward_constants(self) -> None:
        """The constant parts of forward kinematics."""
        nb, M = self.n_bones, self.matrix_local
        inv_local = np.linalg.inv(M)
        offset = M.copy()
        offset[1:] = inv_local[self.parents[1:]] @ M[1:]
        self._offset = readonly(offset)  # parent_rest^-1 @ rest (the root: its rest matrix)
        self._inv_local = readonly(inv_local)
        depth = np.zeros(nb, np.int64)
        for b in range(1, nb):
            depth[b] = depth[self.parents[b]] + 1
        self._doubling_steps = int(np.ceil(np.log2(depth.max() + 1)))
        self._order_groups = [
            (order_axes(m), np.array([b for b in range(nb) if self.rotation_modes[b] == m]))
            for m in EULER_ORDERS
            if m in self.rotation_modes
        ]
        # Index of bone b's rotation DOF for component c: rot_dof[b, c].
        self._rot_dof = readonly(np.arange(nb)[:, None] * 3 + 3 + np.arange(3)[None, :])

    # ------------------------------------------------------------------ construction

    @classmethod
    def from_bones(cls, names, parents, heads, tails, z_axes, **limits) -> Rig:
        """A rig from bone heads, tails and z axes in armature space (the z axis sets the roll).

        Parameters
        ----------
        names, parents
            As for :class:`Rig`.
        heads, tails : (b, 3) array_like
        z_axes : (b, 3) array_like
            A direction for each bone's z axis; only its part perpendicular to the bone is used.
        **limits
            ``lower``, ``upper``, ``locked``, ``rotation_modes`` as for :class:`Rig`.
        """
        H = np.asarray(heads, dtype=np.float64)
        T = np.asarray(tails, dtype=np.float64)
        Z = np.asarray(z_axes, dtype=np.float64)
        names = list(names)
        if H.shape != T.shape or H.shape != Z.shape or H.shape != (len(names), 3):
            raise SolverError(
                f"heads, tails and z_axes must each have shape ({len(names)}, 3), got "
                f"{H.shape}, {T.shape}, {Z.shape}"
            )
        lengths = np.linalg.norm(T - H, axis=1)
        longest = lengths.max(initial=0.0)
        short = np.flatnonzero(~(lengths > MIN_RELATIVE_LENGTH * max(longest, 1e-300)))
        if short.size:
            raise SolverError(
                f"bones {describe_ids(short)} ({', '.join(names[i] for i in short[:5])}) have zero length "
                "(head == tail)",
                bones=short,
            )
        y = (T - H) / lengths[:, None]
        z = Z - (Z * y).sum(1, keepdims=True) * y
        zn = np.linalg.norm(z, axis=1)
        bad = np.flatnonzero(~(zn > 1e-9 * np.maximum(np.linalg.norm(Z, axis=1), 1e-300)))
        if bad.size:
            raise SolverError(
                f"bones {describe_ids(bad)} ({', '.join(names[i] for i in bad[:5])}) have a z axis "
                "parallel to the bone",
                bones=bad,
            )
        z /= zn[:, None]
        x = np.cross(y, z)
        M = np.zeros((len(names), 4, 4))
        M[:, :3, 0], M[:, :3, 1], M[:, :3, 2], M[:, :3, 3] = x, y, z, H
        M[:, 3, 3] = 1.0
        return cls(names, parents, M, lengths, **limits)

    def _bone_list(self, ids) -> str:
        ids = np.unique(np.asarray(ids, dtype=np.int64))
        shown = ", ".join(f"{int(i)} {self.names[i]!r}" for i in ids[:6])
        return shown if ids.size <= 6 else f"{shown}, … ({ids.size} in all)"

    def _dof_list(self, ids) -> str:
        ids = np.unique(np.asarray(ids, dtype=np.int64))
        shown = ", ".join(f"{int(i)} ({self.dof_names[i]})" for i in ids[:6])
        return shown if ids.size <= 6 else f"{shown}, … ({ids.size} in all)"

    # ------------------------------------------------------------------ sizes and lookups

    @property
    def deform_bones(self) -> tuple[str, ...]:
        """The bones a skin's weights name, one column each: every bone of the rig."""
        return self.names

    @property
    def deform_owner(self) -> np.ndarray:
        """(b,) the posed bone that moves each deform bone: each bone itself."""
        return np.arange(self.n_bones)

    def segment_weights(self, weights, rest_vertices) -> sparse.csr_matrix:
        """(n, b) weights per skinning matrix: a plain rig's bones each have one, so ``weights`` (n, b)
        themselves, as a CSR matrix (``rest_vertices`` (n, 3) are not needed)."""
        return sparse.csr_matrix(weights)

    @property
    def heads(self) -> np.ndarray:
        """(b, 3) rest head positions."""
        return self.matrix_local[:, :3, 3]

    @property
    def tails(self) -> np.ndarray:
        """(b, 3) rest tail positions."""
        return self.heads + self.lengths[:, None] * self.matrix_local[:, :3, 1]

    def bone_index(self, name: str) -> int:
        """Index of the bone called ``name``."""
        try:
            return self.names.index(name)
        except ValueError:
            raise SolverError(f"the rig has no bone called {name!r}") from None

    def bone_dofs(self, bone: int | str) -> np.ndarray:
        """(6,) DOF indices of the root bone, (3,) of any other, in increasing order."""
        b = self.bone_index(bone) if isinstance(bone, str) else int(bone)
        if not 0 <= b < self.n_bones:
            raise SolverError(f"bone index {b} is out of range 0..{self.n_bones - 1}")
        return np.flatnonzero(self.dof_bone == b)

    @cached_property
    def subtree(self) -> np.ndarray:
        """(b, b) bool: ``subtree[i, j]`` when bone i is bone j or one of its descendants."""
        D = np.eye(self.n_bones, dtype=bool)
        for b in range(1, self.n_bones):
            D[b] |= D[self.parents[b]]
        return readonly(D)

    def check_theta(self, theta, what: str = "theta") -> np.ndarray:
        """(d,) float64 copy of θ; raises SolverError unless it has one finite value per DOF."""
        t = np.array(theta, dtype=np.float64).reshape(-1)
        if t.size != self.n_dofs:
            raise SolverError(f"{what} needs {self.n_dofs} values (one per DOF), got {t.size}")
        bad = np.flatnonzero(~np.isfinite(t))
        if bad.size:
            raise SolverError(
                f"{what} is not finite at DOFs {self._dof_list(bad)}", dofs=bad, bones=self.dof_bone[bad]
            )
        return t

    # ------------------------------------------------------------------ Blender round trip

    def euler(self, theta) -> np.ndarray:
        """(b, 3) each bone's Euler angles (Blender's ``rotation_euler``) at θ (d,)."""
        return self.check_theta(theta)[3:].reshape(-1, 3)

    def rotations(self, theta) -> np.ndarray:
        """(b, 3, 3) each bone's local rotation matrix at θ (d,)."""
        return self._rotations(self.euler(theta))

    def _rotations(self, angles: np.ndarray) -> np.ndarray:
        R = np.empty((self.n_bones, 3, 3))
        for (i, j, k), bones in self._order_groups:
            a = angles[bones]
            R[bones] = axis_rotation(a[:, k], k) @ axis_rotation(a[:, j], j) @ axis_rotation(a[:, i], i)
        return R

    def basis(self, theta) -> np.ndarray:
        """(b, 4, 4) each bone's local transform (Blender's ``pose_bone.matrix_basis``) at θ (d,)."""
        t = self.check_theta(theta)
        B = np.zeros((self.n_bones, 4, 4))
        B[:, :3, :3] = self.rotations(t)
        B[0, :3, 3] = t[:3]
        B[:, 3, 3] = 1.0
        return B

    def theta_from_basis(self, basis, compatible=None) -> np.ndarray:
        """(d,) the DOF vector of local transforms (b, 4, 4) (Blender's ``matrix_basis`` per bone).

        Parameters
        ----------
        basis : (b, 4, 4) array_like
            Rigid local transforms; only the root may translate.
        compatible : (d,) array_like, optional
            A nearby θ: each bone's Euler angles are chosen closest to it (no 2π jumps between keys).

        Raises
        ------
        SolverError
            If a basis is not rigid, or a non-root bone translates (the rig has no such DOF).
        """
        B = np.asarray(basis, dtype=np.float64)
        if B.shape != (self.n_bones, 4, 4) or not np.all(np.isfinite(B)):
            raise SolverError(f"basis must be finite with shape ({self.n_bones}, 4, 4), got {B.shape}")
        R = B[:, :3, :3]
        off = np.abs(R.transpose(0, 2, 1) @ R - np.eye(3)).max(axis=(1, 2))
        bad = np.flatnonzero((off > ORTHONORMAL_TOLERANCE) | (np.linalg.det(R) <= 0))
        if bad.size:
            raise SolverError(
                f"local transforms of bones {self._bone_list(bad)} are not rotations (scale or shear)",
                bones=bad,
            )
        scale = max(float(self.lengths.max()), 1.0)
        moved = np.flatnonzero(np.abs(B[1:, :3, 3]).max(axis=1) > 1e-9 * scale) + 1
        if moved.size:
            raise SolverError(
                f"bones {self._bone_list(moved)} have a location offset; only the root translates",
                bones=moved,
            )
        ref = None if compatible is None else self.check_theta(compatible, "compatible")[3:].reshape(-1, 3)
        theta = np.zeros(self.n_dofs)
        theta[:3] = B[0, :3, 3]
        angles = np.empty((self.n_bones, 3))
        for mode in set(self.rotation_modes):
            bones = np.array([b for b in range(self.n_bones) if self.rotation_modes[b] == mode])
            angles[bones] = matrix_to_euler(R[bones], mode, None if ref is None else ref[bones])
        theta[3:] = angles.ravel()
        return theta

    # ------------------------------------------------------------------ forward kinematics

    def pose_matrices(self, theta) -> np.ndarray:
        """(b, 4, 4) posed armature-space bone matrices (Blender's ``pose_bone.matrix``) at θ (d,)."""
        return self.kinematics(theta, derivatives=False).matrices

    def root_transform(self, theta) -> np.ndarray:
        """(4, 4) the rigid motion θ gives the root bone from its rest placement, armature space:
        ``pose[root] @ matrix_local[root]⁻¹``."""
        M = self.matrix_local[0]
        return M @ self.basis(theta)[0] @ np.linalg.inv(M)

    def root_dofs(self, G, compatible=None) -> np.ndarray:
        """(6,) root DOFs (location, Euler angles) whose :meth:`root_transform` is the rigid motion ``G``
        (4, 4): the root bone's pose matrix becomes ``G @ matrix_local[0]``. ``compatible`` (3,): of the
        equal Euler solutions, the one nearest to these angles."""
        M = self.matrix_local[0]
        B = np.linalg.inv(M) @ np.asarray(G, dtype=np.float64) @ M
        euler = matrix_to_euler(B[:3, :3], self.rotation_modes[0], compatible=compatible)
        return np.concatenate([B[:3, 3], euler])

    def kinematics(self, theta, derivatives: bool = True, dofs=None) -> Kinematics:
        """Forward kinematics of θ (d,), with the DOF axes and pivots unless ``derivatives`` is False
        (for every DOF: they cost next to nothing here, so ``dofs`` is accepted and ignored).

        Chains of parent products are formed by pointer doubling (``log2(depth)`` batched steps instead
        of one step per tree level).
        """
        t = self.check_theta(theta)
        nb, nd = self.n_bones, self.n_dofs
        angles = t[3:].reshape(nb, 3)
        rot = self._rotations(angles)
        local = self._offset.copy()  # parent_rest^-1 @ rest @ basis
        local[0, :3, 3] += self._offset[0, :3, :3] @ t[:3]
        local[:, :3, :3] = local[:, :3, :3] @ rot
        P = local
        ancestor = self.parents.copy()
        for _ in range(self._doubling_steps):
            go = np.flatnonzero(ancestor >= 0)
            P = P.copy()
            P[go] = P[ancestor[go]] @ P[go]
            ancestor[go] = ancestor[ancestor[go]]
        skin = (P @ self._inv_local)[:, :3]
        axes = np.zeros((nd, 3))
        origins = np.zeros((nd, 3))
        if derivatives:
            before = np.empty((nb, 4, 4))  # each bone's frame before its own rotation
            before[0] = self._offset[0]
            before[0, :3, 3] = P[0, :3, 3]
            before[1:] = P[self.parents[1:]] @ self._offset[1:]
            axes[:3] = self.matrix_local[0, :3, :3].T
            Q = before[:, :3, :3]
            for (i, j, k), bones in self._order_groups:
                Rk = axis_rotation(angles[bones, k], k)
                QRk = Q[bones] @ Rk
                axes[self._rot_dof[bones, k]] = Q[bones, :, k]
                axes[self._rot_dof[bones, j]] = QRk[:, :, j]
                axes[self._rot_dof[bones, i]] = (QRk @ axis_rotation(angles[bones, j], j))[:, :, i]
            origins[3:] = np.repeat(before[:, :3, 3], 3, axis=0)
        return Kinematics(rig=self, matrices=P, skinning=skin, axes=axes, origins=origins)
