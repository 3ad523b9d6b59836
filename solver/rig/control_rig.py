"""The solver's rig for a production rig's hand: controls in, deform-bone skinning matrices and their exact
derivatives out (see :mod:`solver.rig.controls` for what is solved and why).

:class:`ControlRig` stands where :class:`solver.Rig` stands for :class:`solver.SkinnedMesh` and
:class:`solver.ContactIK`. Its DOFs are the root control's three location channels and rotation vector
(``θ[:6]``, zero where the hand was read), then three Euler angles per finger control (their own, or for
quaternion and axis-angle controls in the order farthest from gimbal lock at the pose read).

Evaluation is compiled once: the bones between the controls and the deform bones are grouped by dependency
depth and by what Blender does to them (:func:`solver.rig.bones.bone_key`,
:func:`solver.rig.constraints.constraint_key`), and each group is posed at once
(:func:`solver.rig.constraints.stack_pose_bones`); the B-Bones bend in stacks too
(:func:`solver.rig.bbone.stack_deform_matrices`). Derivatives are complex steps (:mod:`solver.rig.analytic`)
along one direction per colour of DOFs that no skinning matrix depends on together.
"""

from __future__ import annotations

from collections import defaultdict
from functools import cached_property

import numpy as np
from scipy import sparse
from scipy.spatial.transform import Rotation

from ..errors import SolverError
from ..rotations import EULER_ORDERS, euler_to_matrix, matrix_to_euler
from . import analytic, bbone, bones, constraints, spaces
from .controls import Plan, handles
from .dofs import EulerDofs

#: A location column of the root control shorter than this (times the hand's size) does not move it.
MIN_LOCATION_EFFECT = 1e-9
#: Poses whose skinning matrices a rig keeps (:meth:`ControlRig.kinematics`).
RECENT_POSES = 8


class ControlKinematics:
    """The skinning matrices of one pose of a :class:`ControlRig` and their exact derivatives.

    Attributes
    ----------
    skinning : (s, 3, 4)
        Per deformer (a plain deform bone, or one B-Bone joint), what it does to a rest point.
    tangents : (k, s, 3, 4) or None
        Their derivatives along k seeded directions; ``owners[j, s]`` is the DOF (of ``n_dofs``) whose
        derivative ``tangents[j, s]`` is, or -1 where deformer s depends on no DOF seeded by j.
    """

    def __init__(self, skinning: np.ndarray, tangents: np.ndarray | None, owners=None, n_dofs: int = 0):
        self.skinning = skinning
        self.tangents = tangents
        self.owners = owners
        self.n_dofs = n_dofs

    def pullback(self, sums: np.ndarray) -> np.ndarray:
        """(d,) the gradient from per-deformer gradients ``sums`` (s, 3, 4), as :class:`solver.Kinematics`."""
        per = np.einsum("ksij,sij->ks", self.tangents, sums)
        hit = self.owners >= 0
        return np.bincount(self.owners[hit], weights=per[hit], minlength=self.n_dofs)

    def jacobian(self, weights: np.ndarray, rest: np.ndarray) -> np.ndarray:
        """(m, 3, d) derivatives of ``Σ_s weights[v, s] S_s [rest_v; 1]`` (weights (m, s) dense, rest (m, 3))
        with respect to θ (only the deformers that move these points count: a finger's pads are moved by
        a few of a hand's hundreds of B-Bone segments)."""
        used = np.flatnonzero(np.any(weights != 0, axis=0))
        n_deformers = len(used)
        full = np.zeros((n_deformers, 4, self.n_dofs, 3))  # (s, column, DOF, row)
        j, s = np.nonzero(self.owners[:, used] >= 0)
        full[s, :, self.owners[j, used[s]]] = self.tangents[j, used[s]].transpose(0, 2, 1)
        # Σ_s w[v, s] dS_s/dθ [rest_v; 1]: one product of the weighted homogeneous points (m, 4 s)
        homogeneous = np.concatenate([rest, np.ones((len(rest), 1))], axis=1)
        X = (weights[:, used, None] * homogeneous[:, None, :]).reshape(len(rest), 4 * n_deformers)
        return (
            (X @ full.reshape(4 * n_deformers, 3 * self.n_dofs))
            .reshape(len(rest), self.n_dofs, 3)
            .swapaxes(1, 2)
        )


class ControlRig(EulerDofs):
    """A production rig's hand as the solver's rig: controls in, deform-bone skinning matrices out.

    Parameters
    ----------
    plan : Plan
        From :meth:`~.controls.Armature.plan`; it must have no blockers.

    Attributes
    ----------
    names : tuple of str
        The posed bones: the root control (or the hand root, when the root is fixed), then the finger
        controls. ``parents`` links each finger control to the nearest posed bone above it.
    deform_bones : tuple of str
        The skin weights' columns.
    """

    def __init__(self, plan: Plan):
        if not plan.ok:
            raise SolverError(
                f"contact IK cannot reproduce how '{plan.armature.name}' poses the hand: "
                f"{plan.describe_blockers()}"
            )
        self.plan = plan
        arm = plan.armature
        self.armature = arm
        self.deform_bones = plan.deform
        root_name = plan.root if plan.root is not None else plan.hand_root
        self.names: tuple[str, ...] = (root_name, *plan.controls)
        self._lay_out_dofs()
        self.parents = self._control_parents()
        self._root_frame()
        self.orders = self._orders()
        self.start = self._start_pose()
        self._limits()
        self._order = self._ordering()

    # ------------------------------------------------------------------ structure

    def _control_parents(self) -> np.ndarray:
        index = {n: i for i, n in enumerate(self.names)}
        parents = [-1]
        for n in self.names[1:]:
            up = next((u for u in self.armature.parent_chain(n)[1:] if u in index), None)
            parents.append(index[up] if up is not None else 0)
        return np.array(parents, dtype=np.int64)

    def _root_frame(self) -> None:
        """The root's pivot, rotation frame and location directions, from the root control's pose."""
        arm, plan = self.armature, self.plan
        self._root_locked = np.ones(6, bool)
        self._pivot = np.zeros(3)
        self._frame = np.eye(3)
        self._moves = np.zeros((3, 3))
        if plan.root is None:
            return
        c = arm[plan.root]
        M = c.matrix
        self._pivot = M[:3, 3].copy()
        self._frame = M[:3, :3] / np.linalg.norm(M[:3, :3], axis=0)
        # How each location channel moves the control's head: exact derivative of Blender's placement.
        parent = arm[c.parent] if c.parent else None
        parent_pose = parent.matrix if parent else None
        X = np.repeat(c.location[None].astype(np.complex128), 3, axis=0)
        X[np.arange(3), np.arange(3)] += 1j * analytic.STEP
        rotation = bones.rotation_matrix(c.bone.rotation_mode, c.rotation)
        local = bones.channel_matrix(X, rotation, c.scale)
        placed = constraints.pose_bone(
            c.bone, parent.bone if parent else None, parent_pose, local, (), {}, arm.world
        )
        head = placed[:, :3, 3]
        self._moves = analytic.derivative(head).T  # (3, 3): column k is d head / d location_k
        size = max(np.linalg.norm(arm[plan.hand_root].bone.matrix_local[:3, 3]), 1.0)
        effect = np.linalg.norm(self._moves, axis=0) > MIN_LOCATION_EFFECT * size
        self._root_locked[:3] = np.array(c.lock_location) | ~effect
        self._root_locked[3:] = np.array(c.lock_rotation)

    def _orders(self) -> tuple[str, ...]:
        """Each finger control's Euler order: its own, or for quaternion and axis-angle controls the order
        whose middle angle is smallest at the current pose (farthest from gimbal lock)."""
        orders = []
        for n in self.names[1:]:
            b = self.armature[n]
            mode = b.bone.rotation_mode
            if mode in EULER_ORDERS:
                orders.append(mode)
                continue
            R = bones.rotation_matrix(mode, b.rotation)
            middle = [abs(matrix_to_euler(R, o)["XYZ".index(o[1])]) for o in EULER_ORDERS]
            orders.append(EULER_ORDERS[int(np.argmin(middle))])
        return ("XYZ", *orders)

    def _start_pose(self) -> np.ndarray:
        theta = np.zeros(self.n_dofs)
        for i, n in enumerate(self.names[1:], start=1):
            b = self.armature[n]
            if b.bone.rotation_mode in EULER_ORDERS:
                theta[3 + 3 * i : 6 + 3 * i] = b.rotation
            else:
                R = bones.rotation_matrix(b.bone.rotation_mode, b.rotation)
                theta[3 + 3 * i : 6 + 3 * i] = matrix_to_euler(R, self.orders[i])
        return theta

    def _limits(self) -> None:
        """Bounds: a turn either way, narrowed by an Euler control's limits, widened to hold the pose read
        (a control outside its limits may stay there); locks from the controls'."""
        nd = self.n_dofs
        lower = np.where(self.is_rotation, -np.pi, -np.inf)
        upper = -lower
        locked = np.zeros(nd, bool)
        locked[:6] = self._root_locked
        for i, n in enumerate(self.names[1:], start=1):
            b = self.armature[n]
            dofs = slice(3 + 3 * i, 6 + 3 * i)
            locked[dofs] = b.lock_rotation
            if b.lower is not None and b.bone.rotation_mode in EULER_ORDERS:
                lower[dofs] = np.maximum(lower[dofs], b.lower)
                upper[dofs] = np.minimum(upper[dofs], b.upper)
        lower[3:], upper[3:] = np.minimum(lower[3:], self.start[3:]), np.maximum(upper[3:], self.start[3:])
        self.lower, self.upper, self.locked = lower, upper, locked

    # ------------------------------------------------------------------ the evaluation program

    def _ordering(self) -> list[tuple[str, str]]:
        """The bones and B-Bones to evaluate, in dependency order: ``("rigid", name)`` moves with the root,
        ``("pose", name)`` is posed as Blender does, ``("bbone", name)`` bends a B-Bone."""
        arm, plan = self.armature, self.plan
        order, state = [], {}

        def visit(n):  # depth-first topological sort over the evaluated bones
            if state.get(n) == 2:
                return
            if state.get(n) == 1:
                raise SolverError(f"the bones of '{arm.name}' depend on each other in a cycle through {n!r}")
            state[n] = 1
            if n in plan.needed:
                for up in sorted(arm.inputs[n] & (plan.needed | plan.rigid)):
                    visit(up)
            state[n] = 2
            order.append(n)

        for n in sorted(plan.needed | plan.rigid, key=list(arm.bones).index):
            visit(n)
        program = [("rigid" if n in plan.rigid else "pose", n) for n in order]
        program += [("bbone", n) for n in plan.deform if arm[n].bbone is not None]
        return program

    @cached_property
    def _targets(self) -> dict[str, list[str]]:
        """Per bone, the bones its constraints read (targets and custom spaces)."""
        return {
            n: sorted(
                {t.subtarget for c in b.constraints for t in c.targets if t.subtarget}
                | {c.space_subtarget for c in b.constraints if c.space_subtarget}
            )
            for n, b in self.armature.bones.items()
        }

    @cached_property
    def _control_index(self) -> dict[str, int]:
        return {n: i for i, n in enumerate(self.names) if i > 0}

    def _root_transform(self, X: np.ndarray) -> np.ndarray:
        """(k, 4, 4) the hand root's rigid motion for DOF rows X (k, d): location channels then a rotation
        vector in the root control's frame, about its head."""
        k = len(X)
        w = X[:, 3:6] @ self._frame.T  # rotation vector in armature axes
        R = rotation_vector_matrix(w)
        T = np.zeros((k, 4, 4), dtype=X.dtype)
        T[:, :3, :3] = R
        T[:, :3, 3] = self._pivot - np.einsum("kij,j->ki", R, self._pivot) + X[:, :3] @ self._moves.T
        T[:, 3, 3] = 1.0
        return T

    @cached_property
    def _compiled(self) -> _Program:
        return _Program(self)

    def _evaluate(self, X: np.ndarray) -> np.ndarray:
        """(k, s, 4, 4) skinning matrices for DOF rows X (k, d) (real, or complex-step directions)."""
        return self._compiled.evaluate(X)

    @cached_property
    def deform_owner(self) -> np.ndarray:
        """(b,) the posed bone (index into ``names``) that moves each deform bone: of the controls whose
        DOFs it depends on, the one whose head is nearest its own (Rigify's DEF-f_index.02 follows
        f_index.02, though f_index.01's DOFs move it too); the root when no finger control does."""
        depends = self._bone_dofs
        owners = []
        for n in self.deform_bones:
            head = self.armature[n].bone.head_local
            found = {int(self.dof_bone[d]) for d in depends[n]} - {0}
            best = min(
                found,
                key=lambda i: np.linalg.norm(self.armature[self.names[i]].bone.head_local - head),
                default=0,
            )
            owners.append(best)
        return np.array(owners, dtype=np.int64)

    def segment_weights(self, weights, rest_vertices) -> sparse.csr_matrix:
        """(n, s) each vertex's weight per deformer, from ``weights`` (n, b) per deform bone (sparse or
        dense, in ``deform_bones`` order) and ``rest_vertices`` (n, 3): a B-Bone's weight split between the
        two segments its rest position falls between (Blender's ``b_bone_deform``), a plain bone's kept."""
        W = sparse.csc_matrix(weights)
        X = np.asarray(rest_vertices, dtype=np.float64)
        columns = []
        for j, n in enumerate(self.deform_bones):
            col = W[:, j].tocoo()
            b = self.armature[n].bbone
            if b is None:
                columns.append(
                    sparse.csr_matrix((col.data, (col.row, np.zeros_like(col.row))), shape=(len(X), 1))
                )
                continue
            index, blend = bbone.vertex_segments(b, X[col.row])
            rows = np.concatenate([col.row, col.row])
            cols = np.concatenate([index, index + 1])
            vals = np.concatenate([col.data * (1 - blend), col.data * blend])
            columns.append(sparse.csr_matrix((vals, (rows, cols)), shape=(len(X), b.segments + 1)))
        return sparse.hstack(columns).tocsr()

    # ------------------------------------------------------------------ the rig interface

    def bone_index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise SolverError(f"{name!r} is not a control the solve poses") from None

    def check_theta(self, theta, what: str = "theta") -> np.ndarray:
        """(d,) float64 copy of θ; raises SolverError (naming ``what``) unless it has one finite value per
        DOF."""
        t = np.array(theta, dtype=np.float64).reshape(-1)
        if t.size != self.n_dofs:
            raise SolverError(f"{what} needs {self.n_dofs} values (one per DOF), got {t.size}")
        bad = np.flatnonzero(~np.isfinite(t))
        if bad.size:
            raise SolverError(f"{what} is not finite at DOFs {', '.join(self.dof_names[i] for i in bad[:5])}")
        return t

    def kinematics(self, theta, derivatives: bool = True, dofs=None) -> ControlKinematics:
        """Skinning matrices at pose θ (d,) and, unless ``derivatives`` is False, their derivatives with
        respect to the DOFs ``dofs`` (indices, default all; the others' derivatives are left out as zero).

        Derivatives are complex steps along one direction per *colour* of DOFs, not per DOF: DOFs that no
        skinning matrix depends on together (the index finger's and the ring finger's) share a colour and
        are stepped at once, and each matrix's derivative along a colour is its derivative with respect
        to its one DOF of that colour (Curtis-Powell-Reid seeding). A hand needs about a third as many
        directions as it has DOFs.
        """
        t = self.check_theta(theta)
        pose = t.tobytes()
        if not derivatives:
            skinning = self._recent.get(pose)
            if skinning is None:
                skinning = np.ascontiguousarray(self._evaluate(t[None])[0][:, :3].real)
                self._remember(pose, skinning)
            return ControlKinematics(skinning, None)
        key = None if dofs is None else tuple(np.asarray(dofs, dtype=np.int64).tolist())
        seeds, owners = self._seeding(key)
        X = t[None] + 1j * analytic.STEP * seeds
        S = self._evaluate(X.astype(np.complex128))
        skinning = analytic.value(S)[:, :3]
        self._remember(pose, skinning)
        return ControlKinematics(skinning, analytic.derivative(S)[:, :, :3], owners, self.n_dofs)

    def _remember(self, pose: bytes, skinning: np.ndarray) -> None:
        """Keep the skinning matrices of the last :data:`RECENT_POSES` poses evaluated: a solve asks again
        for the pose its last stage ended on (its energy, the patches' gaps, how deep the skin lies),
        and one evaluation of this rig costs about as much as a whole solve's step of a plain one."""
        skinning.flags.writeable = False
        self._recent[pose] = skinning
        if len(self._recent) > RECENT_POSES:
            del self._recent[next(iter(self._recent))]

    @cached_property
    def _recent(self) -> dict[bytes, np.ndarray]:
        return {}

    def _seeding(self, dofs: tuple[int, ...] | None) -> tuple[np.ndarray, np.ndarray]:
        """The complex-step seeds (k, d) for the given DOFs (default all) and, per seed and deformer, the
        DOF whose derivative it carries (k, s; -1: none)."""
        cached = self._seedings.get(dofs)
        if cached is not None:
            return cached
        wanted = np.zeros(self.n_dofs, bool)
        wanted[list(dofs) if dofs is not None else slice(None)] = True
        depends = self._deformer_dofs & wanted[None, :]  # (s, d)
        colour = np.full(self.n_dofs, -1)
        for d in np.flatnonzero(wanted):  # greedy colouring of the DOFs' conflict graph
            rows = depends[:, d]
            taken = set(colour[np.flatnonzero(depends[rows].any(axis=0))].tolist())
            colour[d] = next(c for c in range(self.n_dofs) if c not in taken)
        k = max(int(colour.max()) + 1, 1)
        seeds = np.zeros((k, self.n_dofs))
        seeds[colour[wanted], np.flatnonzero(wanted)] = 1.0
        owners = np.full((k, depends.shape[0]), -1)
        s_idx, d_idx = np.nonzero(depends)
        owners[colour[d_idx], s_idx] = d_idx
        self._seedings[dofs] = (seeds, owners)
        return seeds, owners

    @cached_property
    def _seedings(self) -> dict:
        return {}

    @cached_property
    def _posed_dofs(self) -> dict[str, set[int]]:
        """Per bone the evaluation poses, the DOFs its pose depends on (its own and its inputs')."""
        arm, plan = self.armature, self.plan
        own: dict[str, set[int]] = {n: set(range(6)) for n in plan.rigid}
        for n, i in self._control_index.items():
            own[n] = set(range(3 + 3 * i, 6 + 3 * i))
        deps: dict[str, set[int]] = {}
        for kind, n in self._order:
            if kind == "bbone":
                continue
            found = set(own.get(n, ()))
            if kind == "pose":
                for up in arm.inputs[n]:
                    found |= deps.get(up, set())
            deps[n] = found
        return deps

    @cached_property
    def _bone_dofs(self) -> dict[str, set[int]]:
        """Per deform bone, the DOFs its skinning matrices depend on (through its pose and its handles)."""
        arm, deps = self.armature, self._posed_dofs
        out = {}
        for n in self.deform_bones:
            found = set(deps.get(n, ()))
            b = arm[n].bbone
            for h in handles(b) if b is not None else ():
                found |= deps.get(h, set())
            out[n] = found
        return out

    @cached_property
    def _deformer_dofs(self) -> np.ndarray:
        """(s, d) bool: which DOFs each skinning matrix depends on."""
        rows = []
        for n in self.deform_bones:
            row = np.zeros(self.n_dofs, bool)
            row[list(self._bone_dofs[n])] = True
            b = self.armature[n].bbone
            rows += [row] * (1 if b is None else b.segments + 1)
        return np.array(rows).reshape(-1, self.n_dofs)

    def root_transform(self, theta) -> np.ndarray:
        """(4, 4) the rigid motion θ gives the hand root (and the root control), armature space."""
        return self._root_transform(self.check_theta(theta)[None])[0].real

    def root_dofs(self, G, compatible=None) -> np.ndarray:
        """(6,) root DOFs whose :meth:`root_transform` is the rigid motion ``G`` (4, 4) (armature space),
        as near it as the root's location channels reach when they cannot move it every way (the
        translation's least-squares fit). The rotation vector is the one of length at most π, or with
        ``compatible`` (3,) the one of its turns nearest to that (no jumps of a turn between frames)."""
        G = np.asarray(G, dtype=np.float64)
        w = Rotation.from_matrix(G[:3, :3]).as_rotvec()  # armature axes
        R = rotation_vector_matrix(w[None])[0]
        location = np.linalg.lstsq(self._moves, G[:3, 3] - self._pivot + R @ self._pivot, rcond=None)[0]
        turn = np.linalg.solve(self._frame, w)  # the root control's axes
        size = np.linalg.norm(turn)
        if compatible is not None and size > 0:
            axis = turn / size
            turn = turn + 2 * np.pi * np.round((np.dot(compatible, axis) - size) / (2 * np.pi)) * axis
        return np.concatenate([location, turn])

    def rotations(self, theta) -> dict[str, np.ndarray]:
        """Each finger control's rotation matrix (3, 3) at θ (its channel rotation)."""
        t = self.check_theta(theta)
        return {
            n: euler_to_matrix(t[3 + 3 * i : 6 + 3 * i], self.orders[i])
            for n, i in self._control_index.items()
        }


class _Program:
    """The compiled evaluation of a :class:`ControlRig`: every bone it poses, in stacks by dependency depth
    and by what Blender does to them, in one store of pose matrices ``(bones, directions, 4, 4)``."""

    def __init__(self, rig: ControlRig):
        arm, plan = rig.armature, rig.plan
        self.rig = rig
        evaluated = [n for kind, n in rig._order if kind in ("pose", "rigid")]
        used = set(evaluated)
        for n in evaluated:
            b = arm[n]
            used |= {b.parent} if b.parent else set()
            for t in rig._targets[n]:
                used |= {t} | ({arm[t].parent} if arm[t].parent else set())
        for n in plan.deform:
            used.add(n)
            b = arm[n].bbone
            used |= set(handles(b)) if b is not None else set()
        self.names = [n for n in arm.bones if n in used]
        index = {n: i for i, n in enumerate(self.names)}
        self.index = index
        self.initial = np.stack([arm[n].matrix for n in self.names])[:, None]
        self.rigid = np.array([index[n] for n in evaluated if n in plan.rigid], dtype=np.int64)
        self.rigid_rest = self.initial[self.rigid]
        self.world = spaces.World.of(arm.world)
        self._controls(rig, index)
        self.stacks = self._stacks(rig, [n for n in evaluated if n not in plan.rigid], index)
        root = set(range(6))
        for st in self.stacks:
            st["root_only"] = all(rig._posed_dofs[self.names[i]] <= root for i in st["out"])
        self._root_pose: bytes | None = None  # the root DOFs the kept root-only stacks were posed at
        self._root_posed: dict[int, np.ndarray] = {}
        self._deformers(rig, index)

    def _controls(self, rig: ControlRig, index) -> None:
        """The controls' channel matrices come from θ, per Euler order in one call."""
        arm = rig.armature
        groups = defaultdict(list)
        for n, i in rig._control_index.items():
            groups[rig.orders[i]].append((n, i))
        self.control_groups = []
        self.control_column = {}
        column = 0
        for order, members in groups.items():
            dofs = np.array([[3 + 3 * i, 4 + 3 * i, 5 + 3 * i] for _, i in members])
            location = np.stack([arm[n].location for n, _ in members])
            scale = np.stack([arm[n].scale for n, _ in members])
            self.control_groups.append((order, dofs, location, scale))
            for n, _ in members:
                self.control_column[n] = column
                column += 1

    def _stacks(self, rig: ControlRig, order: list[str], index) -> list[dict]:
        arm = rig.armature
        info = {}
        for n in order:
            b = arm[n]
            parent = arm[b.parent].bone if b.parent else None
            targets = {}
            for t in rig._targets[n]:
                targets[t] = arm[t].bone
                if arm[t].parent:
                    targets[arm[t].parent] = arm[arm[t].parent].bone
            key = (
                bones.bone_key(b.bone, parent),
                tuple(constraints.constraint_key(c, targets, b.bone) for c in b.constraints),
            )
            inputs = {up for up in arm.inputs[n] if up in index}
            info[n] = (key, parent, targets, inputs)
        # As late as possible: a bone's level is one less than its earliest reader's, so that like bones
        # at different depths from the controls (the fingers off different palm bones) share a stack.
        readers = defaultdict(set)
        for n in order:
            for up in info[n][3]:
                readers[up].add(n)
        depth: dict[str, int] = {}
        for n in reversed(order):
            depth[n] = min((depth[r] for r in readers[n] if r in depth), default=len(order)) - 1
        groups = defaultdict(list)
        for n in order:
            groups[(depth[n], info[n][0])].append(n)
        stacks = []
        for (_, _), members in sorted(groups.items(), key=lambda item: item[0][0]):
            pose_bones = [arm[n] for n in members]
            targets = {}
            for n in members:
                targets.update(info[n][2])
            bone_stack = bones.BoneStack.of([b.bone for b in pose_bones], [info[n][1] for n in members])
            cstacks = [
                constraints.ConstraintStack.of(
                    [b.constraints[i] for b in pose_bones], [b.bone for b in pose_bones], targets
                )
                for i in range(len(pose_bones[0].constraints))
            ]

            def rows(names):
                return None if names is None else np.array([index[x] for x in names], dtype=np.int64)

            locals_ = np.stack([b.local for b in pose_bones])
            controls = [
                (j, self.control_column[n]) for j, n in enumerate(members) if n in self.control_column
            ]
            stacks.append(
                dict(
                    out=rows(members),
                    bones=bone_stack,
                    constraints=cstacks,
                    parent=rows([b.parent for b in pose_bones])
                    if constraints.parent_needed(bone_stack, cstacks)
                    else None,
                    inputs=[[rows(names) for names in cs.inputs] for cs in cstacks],
                    parent_inputs=[[rows(names) for names in cs.parent_inputs] for cs in cstacks],
                    local=None if not controls and np.all(locals_ == np.eye(4)) else locals_,
                    control_rows=np.array([j for j, _ in controls], dtype=np.int64),
                    control_columns=np.array([c for _, c in controls], dtype=np.int64),
                )
            )
        return stacks

    def _deformers(self, rig: ControlRig, index) -> None:
        """Where each deform bone's skinning matrices come from: its pose times its inverse rest matrix, or
        its B-Bone stack's joints."""
        arm = rig.armature
        columns, start = {}, 0
        for n in rig.deform_bones:
            count = 1 if arm[n].bbone is None else arm[n].bbone.segments + 1
            columns[n] = np.arange(start, start + count)
            start += count
        self.n_deformers = start
        plain = [n for n in rig.deform_bones if arm[n].bbone is None]
        self.plain_rows = np.array([index[n] for n in plain], dtype=np.int64)
        self.plain_columns = np.array([columns[n][0] for n in plain], dtype=np.int64)
        self.plain_inverse = (
            np.stack([np.linalg.inv(arm[n].bone.matrix_local) for n in plain])[:, None] if plain else None
        )
        self.bbone_stacks = []
        for stack in bbone.stacks([arm[n].bbone for n in rig.deform_bones if arm[n].bbone is not None]):
            slots = (stack.names, *stack.handle_names, *stack.handle_parent_names)
            rows = [
                None
                if names is None
                else np.array(
                    [index[own if n is None else n] for n, own in zip(names, stack.names, strict=True)]
                )
                for names in slots
            ]  # a bone without a handle gets its own pose in the handle's place, unread
            self.bbone_stacks.append((stack, rows, np.stack([columns[n] for n in stack.names])))

    def evaluate(self, X: np.ndarray) -> np.ndarray:
        """(k, s, 4, 4) the skinning matrices for DOF rows X (k, d): a real pose, or complex-step
        directions sharing one real pose."""
        rig = self.rig
        k = len(X)
        shared = bool(np.iscomplexobj(X))
        store = np.empty((len(self.names), k, 4, 4), dtype=X.dtype)
        store[:] = self.initial
        store[self.rigid] = rig._root_transform(X)[None] @ self.rigid_rest
        control_locals = self._control_locals(X)
        root = self._hold_root(X)
        for i, st in enumerate(self.stacks):
            if root and i in self._root_posed:
                store[st["out"]] = self._root_posed[i]
                continue
            local = st["local"]
            if st["control_rows"].size:
                L = np.array(np.broadcast_to(local[:, None], (len(local), k, 4, 4)), dtype=X.dtype)
                L[st["control_rows"]] = control_locals[:, st["control_columns"]].swapaxes(0, 1)
                local = L.swapaxes(0, 1)
            out = constraints.stack_pose_bones(
                st["bones"],
                self._view(store, st["parent"]),
                local,
                st["constraints"],
                [[self._view(store, i) for i in ins] for ins in st["inputs"]],
                [[self._view(store, i) for i in ins] for ins in st["parent_inputs"]],
                self.world,
                shared=shared,
            )
            store[st["out"]] = out.swapaxes(0, 1)
            if root and st["root_only"]:
                self._root_posed[i] = store[st["out"], :1].real  # a copy already (fancy indexing)
        S = np.empty((k, self.n_deformers, 4, 4), dtype=X.dtype)
        if self.plain_inverse is not None:
            S[:, self.plain_columns] = (store[self.plain_rows] @ self.plain_inverse).swapaxes(0, 1)
        for stack, rows, columns in self.bbone_stacks:
            joints = bbone.stack_deform_matrices(
                stack, *(None if r is None else store[r].swapaxes(0, 1) for r in rows)
            )
            S[:, columns] = np.broadcast_to(joints, (k, *joints.shape[-4:]))
        return S

    def _hold_root(self, X: np.ndarray) -> bool:
        """Whether the rows X (k, d) share one root pose and step no root DOF, so that the stacks only
        the root moves (the arm's, on a production rig: 17 of the Rigify hand's 38) are posed as they
        were at the last call with that root pose, kept: a solve of the fingers alone evaluates them once.
        What was kept at another root pose is dropped."""
        root = X[:, :6]
        if np.iscomplexobj(X) and np.any(root.imag):
            return False
        if np.any(root.real != root[:1].real):
            return False
        key = root[0].real.tobytes()
        if key != self._root_pose:
            self._root_pose = key
            self._root_posed.clear()
        return True

    @staticmethod
    def _view(store, rows):
        return None if rows is None else store[rows].swapaxes(0, 1)

    def _control_locals(self, X: np.ndarray) -> np.ndarray:
        """(k, controls, 4, 4) the finger controls' channel matrices at DOF rows X."""
        out = []
        for order, dofs, location, scale in self.control_groups:
            R = euler_to_matrix(X[:, dofs], order)
            out.append(bones.channel_matrix(location, R, scale))
        if not out:
            return np.zeros((len(X), 0, 4, 4), dtype=X.dtype)
        return out[0] if len(out) == 1 else np.concatenate(out, axis=1)


def rotation_vector_matrix(w: np.ndarray) -> np.ndarray:
    """(k, 3, 3) rotation matrices ``exp([w]x)`` of rotation vectors (k, 3), analytic at w = 0 too."""
    t2 = np.sum(w * w, axis=-1)
    small = np.abs(t2.real) < 1e-8
    t = np.sqrt(np.where(small, 1.0, t2))
    a = np.where(small, 1 - t2 / 6 + t2 * t2 / 120, np.sin(t) / t)
    b = np.where(small, 0.5 - t2 / 24 + t2 * t2 / 720, (1 - np.cos(t)) / np.where(small, 1.0, t2))
    K = np.zeros((*w.shape[:-1], 3, 3), dtype=w.dtype)
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -w[..., 2], w[..., 1], -w[..., 0]
    K = K - np.swapaxes(K, -1, -2)
    return np.eye(3) + a[..., None, None] * K + b[..., None, None] * (K @ K)
