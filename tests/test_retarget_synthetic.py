"""Synthetic manipulations with ground truth (solver.retarget.synthetic), checked against independent
oracles: the rig's own skinning, exact signed distances (solver.MeshSDF), the rig's root bone, finite
differences and the reflection that defines the left hand."""

import numpy as np
import pytest

from solver import MeshSDF
from solver.hands import make_hand
from solver.retarget import synthetic as sy
from solver.retarget.motion import Motion

SHORT = 4 * len(sy.PHASES)  # the fewest frames a motion may have
LONG = 500


@pytest.fixture(scope="module")
def short():
    """Every object at the fewest frames, generated once (lazily) for the module."""
    cache = {}

    def get(name: str) -> Motion:
        if name not in cache:
            cache[name] = sy.generate(name, frames=SHORT, seed=0)
        return cache[name]

    return get


@pytest.fixture(scope="module")
def long() -> Motion:
    """A full-length motion: 500 frames at 120 fps."""
    return sy.generate("cylinder", frames=LONG, fps=120.0, seed=3)


@pytest.fixture(scope="module")
def hand():
    return make_hand("human")


def _world(points, V_or_mesh_vertices, faces):
    return np.einsum("kc,kcd->kd", points.bary, V_or_mesh_vertices[faces[points.faces]])


def _apply(T, X):
    return X @ T[:3, :3].T + T[:3, 3]


def _held_frames(m: Motion) -> tuple[int, int]:
    """First and last frame at which the object is off its start and end poses (lifted .. placed)."""
    P = m.object_poses.reshape(m.n_frames, -1)
    off_start = np.flatnonzero(np.abs(P - P[0]).max(1) > 0)
    off_end = np.flatnonzero(np.abs(P - P[-1]).max(1) > 0)
    return int(off_start[0]), int(off_end[-1])


# ------------------------------------------------------------------ shape of the data


def test_full_length_motion(long):
    assert long.n_frames == LONG >= 500 and long.fps == 120.0
    assert long.duration == pytest.approx((LONG - 1) / 120)
    assert long.source_kind == "human" and long.source_scale == 1.0
    assert long.source_theta.shape == (LONG, make_hand("human").rig.n_dofs)
    assert long.table is not None and np.all(long.table_size > 0)
    counts = long.object_contacts.count()
    assert np.array_equal(counts, long.hand_contacts.count())
    # No contact while the hand approaches and after it has withdrawn; plenty while it holds.
    assert counts[0] == 0 and counts[-1] == 0
    a, b = _held_frames(long)
    assert counts[a : b + 1].min() >= 20 and np.median(counts[a : b + 1]) >= 50


@pytest.mark.parametrize("name", sy.OBJECTS)
def test_every_object(short, hand, name):
    """Each object: ground truth poses the rig exactly, contacts are paired, on the object's surface and
    in reach of the hand, nothing penetrates, and the object rests, is carried rigidly, and rests."""
    m = short(name)
    assert m.n_frames == SHORT and m.fps == 120.0
    # Ground truth: the vertices are the rig's skinning of the DOF curves (bit for bit).
    rig_hand = sy.source_hand(m.source_kind, m.source_scale)
    for f in range(0, SHORT, 5):
        np.testing.assert_array_equal(m.hand_vertices[f], rig_hand.posed_vertices(m.source_theta[f]))
    # Paired contacts: within the contact tolerance in world space; the object point is the exact
    # closest point to the hand point (MeshSDF, an independent closest-point search).
    sdf = MeshSDF(m.object_mesh)
    tol = sy.CONTACT_TOLERANCE * m.source_scale
    worst_pair = worst_closest = 0.0
    total = 0
    for f in range(SHORT):
        h = _world(m.hand_contacts.frame(f), m.hand_vertices[f], m.hand_mesh.faces)
        o = _apply(
            m.object_poses[f], _world(m.object_contacts.frame(f), m.object_mesh.vertices, m.object_mesh.faces)
        )
        if not len(h):
            continue
        total += len(h)
        gap = np.linalg.norm(h - o, axis=1)
        local = (h - m.object_poses[f, :3, 3]) @ m.object_poses[f, :3, :3]
        d = sdf(local)
        worst_pair = max(worst_pair, gap.max())
        worst_closest = max(worst_closest, np.abs(np.abs(d) - gap).max())
    assert total > 500
    assert worst_pair <= tol * (1 + 1e-9)
    assert worst_closest < 1e-9
    # No penetration of the object or the table beyond the tolerance (penetration() and MeshSDF).
    depth = sy.penetration(m)
    limit = sy.PENETRATION_TOLERANCE * m.source_scale
    for what in ("hand_object", "hand_table", "object_table"):
        assert depth[what].max() <= limit, what
    for f in range(0, SHORT, 4):
        local = (m.hand_vertices[f] - m.object_poses[f, :3, 3]) @ m.object_poses[f, :3, :3]
        assert sdf(local).min() >= -limit
    # The object: still before the lift and after the release, rigidly in the hand between.
    a, b = _held_frames(m)
    assert 0 < a < b < SHORT - 1
    assert np.all(m.object_poses[:a] == m.object_poses[0]) and np.all(
        m.object_poses[b + 1 :] == m.object_poses[-1]
    )
    assert m.object_poses[-1, 2, 3] == pytest.approx(
        m.object_poses[0, 2, 3], abs=1e-9
    )  # set down on the table
    assert m.object_contacts.count()[a : b + 2].min() > 0  # held from the lift to the release
    _assert_rigidly_held(m, rig_hand, a - 1, b + 1)


def _assert_rigidly_held(m: Motion, rig_hand, a: int, b: int) -> None:
    """The object in the frame of the rig's root bone is the same transform over frames a..b."""
    rel = []
    for f in range(a, b + 1):
        root = rig_hand.rig.pose_matrices(m.source_theta[f])[0]
        rel.append(np.linalg.inv(root) @ m.object_poses[f])
    rel = np.array(rel)
    assert np.abs(rel - rel[0]).max() < 1e-9
    moved = np.linalg.norm(m.object_poses[a:b, :3, 3] - m.object_poses[a, :3, 3], axis=1).max()
    assert moved > 0.1 * m.source_scale  # it was really carried (lifted 16 cm)


def test_long_motion_is_held_rigidly_and_regrips(long, hand):
    a, b = _held_frames(long)
    _assert_rigidly_held(long, sy.source_hand("human"), a - 1, b + 1)
    # The regrip: while the object is held, one finger's contacts vanish and come back.
    owner = np.asarray(hand.weights.argmax(axis=1)).ravel()
    face_bone = owner[hand.mesh.faces[:, 0]]
    frame = long.hand_contacts.frame_index()
    bone = face_bone[long.hand_contacts.faces]
    regripped = []
    for name, bones in hand.chains.items():
        per_frame = np.bincount(frame[np.isin(bone, bones)], minlength=long.n_frames)[a : b + 1]
        touching = per_frame > 0
        first, last = np.argmax(touching), len(touching) - 1 - np.argmax(touching[::-1])
        gap = ~touching[first : last + 1]
        if touching.any() and gap.sum() >= 5:
            regripped.append(name)
        if name == "thumb":
            assert touching.all()  # the thumb never lets go while holding
    assert len(regripped) == 1 and regripped[0] != "thumb"
    # The contact set changes over time: fewer contacts while the finger is off, all back after.
    counts = long.object_contacts.count()[a : b + 1]
    assert counts.min() < 0.9 * np.median(counts) and counts[-1] >= np.median(counts)


def _c2_ratio(theta: np.ndarray, fps: float):
    """Per DOF: max |Δ³θ| / max |Δ²θ|, the change of the finite-difference acceleration per frame against
    its range (about 10/n for a minimum-jerk segment of n frames; ~1 for an acceleration jump)."""
    acc = np.diff(theta, 2, axis=0)
    return np.abs(np.diff(theta, 3, axis=0)).max(0) / np.maximum(np.abs(acc).max(0), 1e-12)


def test_dof_curves_are_c2(long):
    """Finite differences of every DOF: accelerations are bounded and continuous (not the 1/h spike of
    an acceleration jump), the root's Euler angles included (the side grasps keep clear of gimbal lock)."""
    h = 1.0 / long.fps
    theta = long.source_theta
    v = np.diff(theta, axis=0) / h
    acc = np.diff(theta, 2, axis=0) / h**2
    assert np.abs(v[:, :3]).max() < 2.0  # m/s
    assert np.abs(acc[:, :3]).max() < 20.0  # m/s²
    assert np.abs(acc[:, 3:]).max() < 300.0  # rad/s²
    assert _c2_ratio(theta, long.fps).max() < 0.4  # measured 0.33 (the shortest phase, ~21 frames)
    # The same measure flags a curve that is only C¹ (piecewise quadratic with an acceleration jump).
    t = np.arange(LONG) * h
    c = t[LONG // 2]
    kink = np.where(t < c, t**2, c**2 + 2 * c * (t - c))
    assert _c2_ratio(kink[:, None], long.fps).max() > 0.45


# ------------------------------------------------------------------ determinism and scale


def test_determinism(short):
    m0 = short("cylinder")
    sy._cached_grasp.cache_clear()  # recompute the grasp too
    again = sy.generate("cylinder", frames=SHORT, seed=0)
    A, B = m0.to_arrays(), again.to_arrays()
    assert sorted(A) == sorted(B)
    for k in A:
        assert np.asarray(A[k]).tobytes() == np.asarray(B[k]).tobytes(), k
    other = sy.generate("cylinder", frames=SHORT, seed=1)
    assert not np.array_equal(other.source_theta, m0.source_theta)
    assert not np.array_equal(other.object_poses[-1], m0.object_poses[-1])  # set down elsewhere


def test_scale_scales_every_length(short):
    s = 1.3
    m1, ms = short("cylinder"), sy.generate("cylinder", frames=SHORT, seed=0, scale=s)
    assert ms.source_scale == s
    tol = 1e-9
    np.testing.assert_allclose(ms.object_mesh.vertices, s * m1.object_mesh.vertices, atol=tol)
    np.testing.assert_allclose(ms.hand_mesh.vertices, s * m1.hand_mesh.vertices, atol=tol)
    # Up to the flex-to-contact search's tolerance (its bisections do not commute with scaling exactly).
    np.testing.assert_allclose(ms.hand_vertices, s * m1.hand_vertices, atol=2e-5 * s)
    np.testing.assert_allclose(ms.object_poses[:, :3, :3], m1.object_poses[:, :3, :3], atol=1e-7)
    np.testing.assert_allclose(ms.object_poses[:, :3, 3], s * m1.object_poses[:, :3, 3], atol=2e-5 * s)
    np.testing.assert_allclose(ms.table[:3, 3], s * m1.table[:3, 3], atol=tol)
    np.testing.assert_allclose(ms.table_size, s * m1.table_size, atol=tol)
    np.testing.assert_allclose(ms.source_theta[:, :3], s * m1.source_theta[:, :3], atol=2e-5 * s)
    np.testing.assert_allclose(ms.source_theta[:, 6:], m1.source_theta[:, 6:], atol=1e-3)
    c1, cs = m1.object_contacts.count(), ms.object_contacts.count()
    assert np.abs(cs - c1).sum() <= 0.01 * c1.sum()  # the same contacts, up to rounding at the tolerance


def test_bad_arguments():
    with pytest.raises(Exception, match="unknown object"):
        sy.generate("teapot", frames=SHORT)
    with pytest.raises(Exception, match="at least"):
        sy.generate("cylinder", frames=SHORT - 1)
    for kwargs in ({"fps": 0.0}, {"scale": -1.0}, {"density": np.nan}, {"contact_tolerance": 0.0}):
        with pytest.raises(Exception, match="positive"):
            sy.generate("cylinder", frames=SHORT, **kwargs)


# ------------------------------------------------------------------ mirror and bimanual


def test_mirror_hand_and_theta(hand):
    left = sy.mirror_hand(hand)
    rng = np.random.default_rng(7)
    S = np.array([-1.0, 1.0, 1.0])
    for _ in range(3):
        theta = hand.rig.clip(hand.rig.rest + rng.normal(scale=0.4, size=hand.rig.n_dofs))
        mirrored = sy.mirror_theta(hand.rig, theta)
        np.testing.assert_array_equal(sy.mirror_theta(hand.rig, mirrored), theta)  # an involution
        np.testing.assert_array_equal(left.rig.clip(mirrored), mirrored)  # the limits are mirrored too
        np.testing.assert_allclose(left.posed_vertices(mirrored), S * hand.posed_vertices(theta), atol=1e-12)
    # Outward normals: the signed volume stays positive.
    V, Fc = left.mesh.vertices, left.mesh.faces
    volume = np.einsum("ij,ij->i", V[Fc[:, 0]], np.cross(V[Fc[:, 1]], V[Fc[:, 2]])).sum() / 6
    assert volume > 0
    assert sy.source_hand("human-left").mesh.vertices.tobytes() == left.mesh.vertices.tobytes()


def test_bimanual_left_hand_is_the_mirror():
    right, left = sy.bimanual("box", frames=SHORT, seed=0)
    assert right.source_kind == "human" and left.source_kind == "human-left"
    np.testing.assert_array_equal(right.object_poses, left.object_poses)
    n = np.asarray(sy.BIMANUAL_GRASPS["box"].plane, float)
    n /= np.linalg.norm(n)
    lo, hi = right.object_mesh.vertices.min(0), right.object_mesh.vertices.max(0)
    centre = 0.5 * (lo + hi)
    P = np.eye(4)
    P[:3, :3] -= 2 * np.outer(n, n)
    P[:3, 3] = 2 * np.dot(centre, n) * n
    left_hand = sy.source_hand("human-left")
    worst = 0.0
    for f in range(SHORT):
        O = right.object_poses[f]
        W = O @ P @ np.linalg.inv(O)  # the world reflection through the object's symmetry plane
        worst = max(worst, np.abs(left.hand_vertices[f] - _apply(W, right.hand_vertices[f])).max())
        if f % 6 == 0:
            np.testing.assert_array_equal(
                left.hand_vertices[f], left_hand.posed_vertices(left.source_theta[f])
            )
    assert worst < 1e-9
    # The hands stay on their own sides of the plane, and both touch the box while it is held.
    a, b = _held_frames(right)
    for m, sign in ((right, 1), (left, -1)):
        O = m.object_poses[a:b]
        local = np.einsum("fvj,fjk->fvk", m.hand_vertices[a:b] - O[:, None, :3, 3], O[:, :3, :3])
        assert (sign * ((local - centre) @ n)).min() > -1e-3
        assert m.object_contacts.count()[a:b].min() > 0
    assert np.all(sy.penetration(left)["hand_object"] <= sy.PENETRATION_TOLERANCE)
