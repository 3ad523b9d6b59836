"""Pose reachability (Eq. 1 / Eq. 7) minimized by Gauss–Newton in the exponential map (Appendix B).

Given bones that carry device joints (an *assignment*), every other non-root bone is rigid (identity local
rotation) and every root keeps its sample rotation (global orientation is not the device's job). For
each sample pose the joint rotations ``R_j`` minimize

    E_i = Σ_b w_b |n_b − ñ_b(R)|² / (Σ_b w_b · size²)                        (Eq. 7, normalized)

where ``n_b`` are the sample's nodes (bone tails), ``ñ_b`` the nodes the device reaches, ``w_b`` the node
weights and ``size`` the skeleton's characteristic length (so energies are dimensionless and comparable
between rigs). The total is ``E = Σ_i E_i`` (Eq. 6).

Gauss–Newton (Eq. 10–15): each step updates ``R_j ← R_j exp([ω_j]×)`` with ``ω = −(DᵀD)⁻¹ Dᵀ r``
(Eq. 12 reads ``D r``; ``Dᵀ r`` is the Gauss–Newton step). We solve for the step in world axes,
``δ_j = F_j ω_j`` with ``F_j`` the joint bone's posed frame — an orthogonal change of variables —
because then a node ``x`` in the joint's subtree moves by ``δ_j × (x − p_j)`` (``p_j`` the joint's head)
and ``DᵀD`` has closed-form 3×3 blocks built from weighted moments of each joint's subtree nodes (Σw,
Σwx, Σwxxᵀ), with no ``3m × 3l`` Jacobian ever formed. Subtrees of two joints are nested or disjoint, so
block ``(j, k)`` uses the moments of the deeper joint's subtree or is zero. Forward kinematics runs over
the joints only: with every other bone rigid, each node is a fixed offset in the frame of its nearest
jointed ancestor.

Safeguards: a Levenberg–Marquardt damping (relative to the mean diagonal of ``DᵀD``, adapted per pose,
never below :data:`MIN_DAMPING`; steps that raise the energy are rejected) keeps steps finite along
directions no node sees well — the twist of a joint whose nodes nearly lie on its axis, where plain
Gauss–Newton takes steps of tens of radians. The iteration starts from the sample's own rotations (or a
given warm start) and stops by Eq. 15, ``|E^{k+1} − E^k| ≤ 10⁻⁶ |E^{k+1}| + 10⁻⁶``, or after
``max_iterations``. Where residuals stay large (one joint standing in for a long curled chain)
Gauss–Newton converges only linearly, so the energy reached can exceed the minimum by a few parts in a
thousand (tested against a closed-form Kabsch optimum).

Everything is batched: many assignments × all poses are solved at once.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from . import rotations as rot
from .errors import RigError
from .skeleton import Skeleton

__all__ = ["Fit", "fit"]

#: Stopping rule of Eq. (15): relative and absolute tolerance on the per-pose energy.
RELATIVE_TOLERANCE = 1e-6
ABSOLUTE_TOLERANCE = 1e-6
#: Levenberg–Marquardt damping relative to the mean diagonal of DᵀD: start and floor. The floor keeps
#: steps along directions no node sees well (a near-straight chain's twist) from running away.
DAMPING = 1e-3
MIN_DAMPING = 1e-4
#: Work per chunk of assignments (floats of the largest temporaries), to bound memory.
CHUNK_FLOATS = 4_000_000


@dataclass(frozen=True)
class Fit:
    """Best device poses for a batch of assignments.

    Attributes
    ----------
    energy : (c,)
        ``E = Σ_i E_i`` per assignment.
    pose_energy : (c, p)
        ``E_i`` per assignment and pose.
    rotations : (c, p, l, 4)
        Fitted local rotations of each assignment's joints (in the order given; identity padding when
        assignments have fewer than ``l`` joints).
    iterations : (c,)
        Gauss–Newton iterations until every pose of the assignment met Eq. 15.
    """

    energy: np.ndarray
    pose_energy: np.ndarray
    rotations: np.ndarray
    iterations: np.ndarray


def _expm(w: np.ndarray) -> np.ndarray:
    """(..., 3, 3) exp([w]×) of rotation vectors (..., 3): Rodrigues' formula, by scipy, batched."""
    return Rotation.from_rotvec(w.reshape(-1, 3)).as_matrix().reshape(*w.shape, 3)


class _Problem:
    """Sample targets and the rest geometry shared by every assignment."""

    def __init__(self, skeleton: Skeleton, poses):
        Q = skeleton.check_poses(poses, "sample poses")
        if Q.ndim != 3:
            raise RigError(f"sample poses must have shape (p, {skeleton.n_bones}, 4), got {Q.shape}")
        self.skeleton = skeleton
        self.samples = Q
        local = rot.to_matrix(Q)  # (p, m, 3, 3)
        self.targets = skeleton.forward_matrices(local).tails
        M = skeleton.matrix_local
        self.rest_R, self.rest_h = M[:, :3, :3], M[:, :3, 3]
        roots = skeleton.roots
        self.roots = roots
        self.root_frames = self.rest_R[roots] @ local[:, roots]  # (p, r, 3, 3)
        root_of = np.arange(skeleton.n_bones)
        for b, parent in enumerate(skeleton.parents):
            if parent >= 0:
                root_of[b] = root_of[parent]
        self.root_slot = np.searchsorted(roots, root_of)  # position of each bone's root in `roots`
        self.depth = np.zeros(skeleton.n_bones, np.int64)
        for level, bones in enumerate(skeleton.levels):
            self.depth[bones] = level
        self.w = skeleton.weights
        self.scale = 1.0 / (skeleton.weights.sum() * skeleton.size**2)


class _Layout:
    """The reduced kinematics of a chunk of assignments.

    With every unassigned bone rigid, a joint's posed frame is ``F_j = F_a A_j R_j`` and its head
    ``h_j = h_a + F_a t_j``, where ``a`` is its nearest assigned ancestor (or its root) and ``A_j``, ``t_j``
    are rest offsets; every node is ``x_b = h_a + F_a c_b`` for its nearest assigned ancestor-or-self ``a``.
    So forward kinematics runs over the joints only. Joints are sorted by depth (``order``).
    """

    def __init__(self, pr: _Problem, jb: np.ndarray):
        sk = pr.skeleton
        C, l = jb.shape
        depth = np.where(jb >= 0, pr.depth[np.maximum(jb, 0)], np.iinfo(np.int64).max)
        self.order = np.argsort(depth, axis=1, kind="stable")
        jb = np.take_along_axis(jb, self.order, axis=1)
        valid = jb >= 0
        jbc = np.where(valid, jb, 0)
        self.l, self.valid, self.jb = l, valid, jbc
        dj = np.where(valid, pr.depth[jbc] + 1, 0)  # (C, l), 0 for padding
        self.D = (sk.subtree[jbc] & valid[..., None]).astype(np.float64)  # (C, l, m)
        # Anchors: slot of the deepest assigned ancestor(-or-self for nodes), else l + root slot.
        score = self.D * dj[..., None]
        has = score.max(axis=1) > 0
        self.node_anchor = np.where(has, score.argmax(axis=1), l + pr.root_slot[None, :])  # (C, m)
        strict = sk.subtree[jbc[:, None, :], jbc[:, :, None]] & valid[:, None, :] & valid[:, :, None]
        strict &= ~np.eye(l, dtype=bool)
        score = strict * dj[:, None, :]
        has = score.max(axis=2) > 0
        self.joint_anchor = np.where(has, score.argmax(axis=2), l + pr.root_slot[jbc])  # (C, l)
        bone_of = np.concatenate([jbc, np.broadcast_to(pr.roots, (C, pr.roots.size))], axis=1)
        a = np.take_along_axis(bone_of, self.joint_anchor, axis=1)  # (C, l) anchor bones
        Ra = pr.rest_R[a]
        self.A = np.swapaxes(Ra, -1, -2) @ pr.rest_R[jbc]
        self.t = np.einsum("clji,clj->cli", Ra, pr.rest_h[jbc] - pr.rest_h[a])
        a = np.take_along_axis(bone_of, self.node_anchor, axis=1)  # (C, m)
        self.c = np.einsum("cmji,cmj->cmi", pr.rest_R[a], sk.rest_tails[None] - pr.rest_h[a])
        # Normal-equation blocks (j, k) use the moments of the deeper joint's subtree, if nested.
        sub = sk.subtree[jbc[:, :, None], jbc[:, None, :]]  # k in subtree of j
        both = valid[:, :, None] & valid[:, None, :]
        idx = np.arange(l)
        deeper = np.where(
            both & sub, idx[None, None, :], np.where(both & np.swapaxes(sub, 1, 2), idx[None, :, None], -1)
        )
        self.linked = deeper >= 0
        self.deeper = np.where(self.linked, deeper, 0)
        S0 = self.D @ pr.w
        self.S0d = np.where(self.linked, np.take_along_axis(S0[:, None, :], self.deeper, axis=2), 0.0)


def _forward(pr: _Problem, lay: _Layout, R: np.ndarray, cfg: np.ndarray, pose: np.ndarray):
    """Energies (n,), nodes (n, m, 3), joint frames (n, l, 3, 3) and heads (n, l, 3) of rows."""
    n, l = len(cfg), lay.l
    nr = pr.roots.size
    F = np.empty((n, l + nr, 3, 3))
    H = np.empty((n, l + nr, 3))
    F[:, l:] = pr.root_frames[pose]
    H[:, l:] = pr.rest_h[pr.roots]
    rows = np.arange(n)
    for i in range(l):
        a = lay.joint_anchor[cfg, i]
        Fa = F[rows, a]
        H[:, i] = H[rows, a] + np.einsum("nij,nj->ni", Fa, lay.t[cfg, i])
        F[:, i] = Fa @ lay.A[cfg, i] @ R[:, i]
    a = lay.node_anchor[cfg]
    X = H[rows[:, None], a] + np.einsum("nmij,nmj->nmi", F[rows[:, None], a], lay.c[cfg])
    e = X - pr.targets[pose]
    E = pr.scale * np.einsum("nmi,nmi,m->n", e, e, pr.w)
    return E, X, F[:, :l], H[:, :l]


def _chunk_fit(pr: _Problem, jb: np.ndarray, init: np.ndarray, max_iterations: int):
    """Fit a chunk: jb (C, l) bones with -1 padding, init (C, P, l, 4). Returns E (C, P), rotations
    (C, P, l, 4) and iterations (C,)."""
    lay = _Layout(pr, jb)
    C, l = jb.shape
    P = pr.targets.shape[0]
    cfg, pose = np.divmod(np.arange(C * P), P)
    init = np.take_along_axis(init, lay.order[:, None, :, None], axis=2)
    R = rot.to_matrix(init).reshape(C * P, l, 3, 3)
    E, X, F, H = _forward(pr, lay, R, cfg, pose)
    lam = np.full(C * P, DAMPING)
    done = ~lay.valid.any(axis=1)[cfg]
    steps = np.zeros(C * P, np.int64)
    w = pr.w
    eye = np.eye(3 * l)
    for _ in range(max_iterations):
        act = np.flatnonzero(~done)
        if act.size == 0:
            break
        steps[act] += 1
        c, n = cfg[act], act.size
        Xa, Ha = X[act], H[act]
        e = (Xa - pr.targets[pose[act]]) * w[:, None]
        wX = Xa * w[:, None]
        D = lay.D[c]  # (n, l, m)
        S1 = D @ wX  # (n, l, 3)
        S2 = (D @ (wX[..., :, None] * Xa[..., None, :]).reshape(n, -1, 9)).reshape(n, l, 3, 3)
        g = D @ np.cross(Xa, e) - np.cross(Ha, D @ e)  # half the gradient, world axes
        dk = lay.deeper[c]  # (n, l, l)
        rows = np.arange(n)[:, None, None]
        linked = lay.linked[c]
        S1d = np.where(linked[..., None], S1[rows, dk], 0.0)
        S2d = np.where(linked[..., None, None], S2[rows, dk], 0.0)
        pj, pk = Ha[:, :, None, :], Ha[:, None, :, :]
        G = (
            S2d
            - S1d[..., :, None] * pk[..., None, :]
            - pj[..., :, None] * S1d[..., None, :]
            + lay.S0d[c][..., None, None] * pj[..., :, None] * pk[..., None, :]
        )
        blocks = np.trace(G, axis1=-2, axis2=-1)[..., None, None] * np.eye(3) - np.swapaxes(G, -1, -2)
        JtJ = blocks.transpose(0, 1, 3, 2, 4).reshape(n, 3 * l, 3 * l)
        mean = np.maximum(np.trace(JtJ, axis1=-2, axis2=-1) / (3 * l), 1e-300)
        delta = -np.linalg.solve(JtJ + (lam[act] * mean)[:, None, None] * eye, g.reshape(n, 3 * l, 1))
        omega = np.einsum("nlji,nlj->nli", F[act], delta.reshape(n, l, 3)) * lay.valid[c][..., None]
        R_try = R[act] @ _expm(omega)
        E_try, X_try, F_try, H_try = _forward(pr, lay, R_try, c, pose[act])
        better = E_try < E[act]
        small = np.abs(E_try - E[act]) <= RELATIVE_TOLERANCE * np.abs(E_try) + ABSOLUTE_TOLERANCE
        lam[act] = np.where(better, np.maximum(lam[act] * 0.3, MIN_DAMPING), lam[act] * 10.0)
        done[act] = small | (lam[act] > 1e8)
        keep = act[better]
        R[keep], E[keep], X[keep], F[keep], H[keep] = (
            R_try[better],
            E_try[better],
            X_try[better],
            F_try[better],
            H_try[better],
        )
    back = np.argsort(lay.order, axis=1)
    Q = rot.from_matrix(R).reshape(C, P, l, 4)
    Q = np.take_along_axis(Q, back[:, None, :, None], axis=2)
    return E.reshape(C, P), Q, steps.reshape(C, P).max(axis=1)


def _chunks(lengths: list[int], P: int, m: int) -> list[np.ndarray]:
    """Assignments grouped by similar length (sorted), each group within the work budget, so that a long
    chain does not pad many short assignments to its size."""
    order = np.argsort(lengths, kind="stable")
    out, group = [], []
    for i in order:
        l = max(1, lengths[i])
        cost = P * (9 * l * l + 12 * m + 3 * l * m + 1)
        if group and (len(group) + 1) * cost > CHUNK_FLOATS:
            out.append(np.array(group))
            group = []
        group.append(i)
    if group:
        out.append(np.array(group))
    return out


def fit(
    skeleton: Skeleton,
    poses,
    assignments: Sequence[Sequence[int]],
    *,
    init: Sequence[np.ndarray | None] | None = None,
    max_iterations: int = 50,
) -> Fit:
    """Minimize Eq. 7 for every sample pose and every assignment.

    Parameters
    ----------
    skeleton : Skeleton
    poses : (p, b, 4) array_like
        Sample poses (local rotations).
    assignments : sequence of sequences of int
        Bones carrying a joint, per assignment (roots are not allowed: they are posed externally).
    init : sequence of (p, k, 4) arrays or None, optional
        Starting rotations per assignment; rows of NaN (or None for a whole assignment) start from the
        sample's own rotations, as the paper does. Warm starts let a greedy search reuse earlier fits.
    max_iterations : int

    Returns
    -------
    Fit
    """
    problem = _Problem(skeleton, poses)
    P, m = problem.targets.shape[:2]
    lists = [[skeleton.bone_index(b) for b in a] for a in assignments]
    for a in lists:
        roots = [b for b in a if skeleton.parents[b] < 0]
        if roots:
            raise RigError(
                f"root bones {roots} cannot carry a joint (they are posed externally)", bones=roots
            )
        if len(set(a)) != len(a):
            raise RigError(f"an assignment lists a bone twice: {a}", bones=a)
    n = len(lists)
    l = max((len(a) for a in lists), default=0)
    energy = np.zeros((n, P))
    rotations = np.broadcast_to(rot.IDENTITY, (n, P, l, 4)).copy()
    iterations = np.zeros(n, np.int64)
    samples = problem.samples
    for idx in _chunks([len(a) for a in lists], P, m):
        width = max(1, *(len(lists[i]) for i in idx))
        jb = np.full((len(idx), width), -1, np.int64)
        start_rot = np.broadcast_to(rot.IDENTITY, (len(idx), P, width, 4)).copy()
        for r, i in enumerate(idx):
            jb[r, : len(lists[i])] = lists[i]
            start_rot[r, :, : len(lists[i])] = samples[:, lists[i]]
            given = None if init is None else init[i]
            if given is not None:
                given = np.asarray(given, dtype=np.float64).reshape(P, len(lists[i]), 4)
                ok = np.all(np.isfinite(given), axis=-1)
                start_rot[r, :, : len(lists[i])][ok] = given[ok]
        E, Q, it = _chunk_fit(problem, jb, start_rot, max_iterations)
        energy[idx] = E
        rotations[idx, :, :width] = Q
        iterations[idx] = it
    return Fit(energy.sum(axis=1), energy, rotations, iterations)
