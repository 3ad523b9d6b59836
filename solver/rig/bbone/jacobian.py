"""The B-Bone curve differentiated through each bone's state: many complex-step directions of one pose
cost one evaluation of the curve per variable the curve depends on, not one per direction."""

from __future__ import annotations

import numpy as np

from .. import analytic
from .bbone_stack import BBoneStack
from .stacked import stack_joints, stack_state


def stack_jacobian(st: BBoneStack, Pt) -> np.ndarray:
    """(L, g, a, 4, 4) :func:`~solver.rig.bbone.stack_deform_matrices` of complex-step inputs (4, 4, L, g)
    whose real parts agree along L (the L directions of one pose).

    Rather than evaluating the curve on every direction, this evaluates it at the shared value with one
    complex-step direction per variable it depends on, then applies the chain rule with the inputs'
    imaginary parts: the per-bone state s (handles, length, rolls, pose scale, ...) as a function of the
    inputs' top three rows (J1), the joints ``G = diag(1/sc) joints unbend`` as a function of s, and
    ``M = P G``, so that ``dM = dP G + P (dG/ds) J1 dIn``, one matrix product per bone at the end."""
    L, g = Pt[0].shape[2:]
    a = st.segments + 1
    complex_ = [M is not None and np.iscomplexobj(M) for M in Pt]
    entries = [e for e, c in zip(st.entries, complex_, strict=True) if c]
    m_in = sum(len(e) for e in entries)
    steps = st.steps(tuple(complex_), g)  # the inputs' imaginary parts: one direction per entry read
    X, dIn = [], []
    for M, c, e, step in zip(Pt, complex_, st.entries, steps, strict=True):
        if M is None:
            X.append(None)
        elif not c:
            X.append(np.broadcast_to(M.real[:, :, :1], (4, 4, m_in, g)))
        else:
            X.append(analytic.as_complex(M.real[:, :, :1], step))
            dIn.append(M.imag.reshape(16, L, g)[e])
    # the state and its derivatives: on the L directions, or with respect to the inputs' entries
    direct = m_in >= L
    n = L if direct else m_in
    H, length, roll, sc, scale_in, scale_out = stack_state(st, *(Pt if direct else X), shared=True)
    fields = [H.reshape(6, n, g), length[None], roll]
    if st.reads_scale:
        fields += [scale_in, scale_out]
    fields.append(sc)
    state = np.concatenate([np.broadcast_to(f, (f.shape[0], n, g)) for f in fields])  # (m, n, g)
    m = state.shape[0]
    dIn = np.ascontiguousarray(np.concatenate(dIn).transpose(2, 1, 0))  # (g, L, m_in)
    if direct:
        ds = np.ascontiguousarray(state.imag.transpose(2, 1, 0))  # (g, L, m)
    else:
        ds = dIn @ np.ascontiguousarray(state.imag.transpose(2, 1, 0) * (1.0 / analytic.STEP))
    # the joints and their derivatives with respect to the state: a complex-step direction for each
    # variable but the pose scale sc, which only scales the joints' columns (its derivative is the column
    # over sc)
    k = m - 3
    X = analytic.as_complex(state.real[:k, :1], analytic.STEP * np.eye(k)[:, :, None])  # (k, k, g)
    sc0 = state.real[k:, 0]  # (3, g)
    sin, sout = (X[9:12], X[12:15]) if st.reads_scale else (scale_in, scale_out)
    joints = stack_joints(st, X[:6].reshape(3, 2, k, g), X[6], X[7:9], sc0[:, None], sin, sout, shared=True)
    # Z: diag(1 / sc) joints, then its derivatives, per bone and joint (g, a, 3, 4, 1 + m)
    J0 = joints.real[:, :, :, 0].transpose(3, 2, 0, 1)  # (g, a, 3, 4)
    inverse = 1.0 / sc0.T  # (g, 3)
    Z = np.empty((g, a, 3, 4, m + 1))
    np.multiply(J0, inverse[:, None, :, None], out=Z[..., 0])
    np.multiply(
        joints.imag.transpose(4, 2, 0, 1, 3),
        (inverse / analytic.STEP)[:, None, :, None, None],
        out=Z[..., 1 : k + 1],
    )
    Z[..., k + 1 :] = 0.0
    # d/dsc_r: column r of the joints over sc_r, then the derivative of the rows' 1 / sc
    r, rk = np.arange(3), k + 1 + np.arange(3)
    Z[:, :, :, r, rk] = J0[..., :3] * inverse[:, None, :, None] * inverse[:, None, None, :]
    Z[:, :, r, :, rk] -= (J0[:, :, :3] * (inverse * inverse)[:, None, :, None]).transpose(2, 0, 1, 3)
    # P diag(1/sc) joints unbend, per bone and joint as (P ⊗ unbendᵀ) vec(joints)
    P0 = Pt[0].real[:, :, 0].transpose(2, 0, 1)  # (g, 4, 4)
    T = P0[:, None, :3, None, :3, None] * st.unbend_t[:, :, None, :, None, :]  # (g, a, i, k, r, c)
    MK = T.reshape(g, a, 12, 12) @ Z.reshape(g, a, 12, m + 1)  # (g, a, (i, k), value + m)
    MK[:, :, 3::4, 0] += P0[:, None, :3, 3]
    # dM = ds (dM/ds) + dP G, one product (L, m + 12) @ (m + 12, a 12) per bone
    W = np.zeros((g, m + 12, a, 3, 4))
    W[:, :m] = MK[..., 1:].transpose(0, 3, 1, 2).reshape(g, m, a, 3, 4)
    G0 = np.zeros((g, a, 4, 4))
    np.matmul(Z[..., 0], st.unbend_rows, out=G0[:, :, :3])
    G0[:, :, 3, 3] = 1.0
    G0 = G0.transpose(0, 2, 1, 3)  # (g, r, a, k)
    for i in range(3):
        W[:, m + 4 * i : m + 4 * i + 4, :, i, :] = G0
    A = np.zeros((g, L, m + 12))
    A[:, :, :m] = ds
    if complex_[0]:
        A[:, :, m:] = dIn[:, :, :12]
    out = np.empty((L, g, a, 4, 4), np.complex128)
    value = np.empty((g, a, 4, 4))
    value[:, :, :3] = MK[..., 0].reshape(g, a, 3, 4)
    value[:, :, 3] = (0.0, 0.0, 0.0, 1.0)
    out.real[...] = value
    out.imag[..., 3, :] = 0.0
    W = W.reshape(g, m + 12, a * 12)
    for i in range(g):  # bone by bone, to keep the temporary small
        out.imag[:, i, :, :3, :] = (A[i] @ W[i]).reshape(L, a, 3, 4)
    return out
