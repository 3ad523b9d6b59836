"""Pose-space interpolation: exact at samples, convex inside triangles, continuous everywhere."""

import numpy as np
import pytest

from tangible import PoseSpace
from tangible import rotations as rot
from tangible.creatures import creature
from tangible.errors import RigError
from tangible.posespace import blend


@pytest.fixture(scope="module")
def space():
    sk, poses = creature(100, n_poses=12, seed=4)
    driven = [3, 8, 15, 22, 31, 40, 55, 70]
    others = np.setdiff1d(np.arange(sk.n_bones), driven)
    return PoseSpace(poses[:, driven], poses[:, others]), poses[:, driven], poses[:, others]


def test_samples_are_reproduced_exactly(space):
    ps, keys, values = space
    for k, v in zip(keys, values, strict=True):
        assert rot.angle(ps(k), v).max() < 1e-12
    # Also from the other hemisphere: q and -q are one rotation.
    assert rot.angle(ps(-keys[3]), values[3]).max() < 1e-12


def test_blend_is_slerp_on_every_edge_whatever_the_vertex_order():
    rng = np.random.default_rng(1)
    q = rot.normalize(rng.normal(size=(3, 20, 4)))
    for t in (0.0, 0.3, 1.0):
        edge = rot.slerp(q[0], q[1], t)
        assert rot.angle(blend(q, np.array([1 - t, t, 0.0])), edge).max() < 1e-12
        assert rot.angle(blend(q[[1, 2, 0]], np.array([t, 0.0, 1 - t])), edge).max() < 1e-12
        edge = rot.slerp(q[1], q[2], t)
        assert rot.angle(blend(q, np.array([0.0, 1 - t, t])), edge).max() < 1e-12


def test_inside_a_triangle_the_blend_is_convex(space):
    ps, keys, _ = space
    rng = np.random.default_rng(2)
    inside = 0
    for _ in range(60):
        i, j, k = rng.choice(len(keys), 3, replace=False)
        key = rot.slerp(rot.slerp(keys[i], keys[j], rng.uniform()), keys[k], rng.uniform(0, 0.5))
        y = ps.project(key)
        idx, w = ps.weights(key)
        assert np.all(w >= 0) and w.sum() == pytest.approx(1)
        if len(idx) < 3:
            continue
        inside += 1
        np.testing.assert_allclose(w @ ps.points[idx], y, atol=1e-12)  # barycentric coordinates
        out = ps(key)
        # Per bone, the result is a non-negative combination of the three (sign-aligned) samples.
        V = ps.values[idx]
        V = np.where(np.sum(V * out, axis=-1, keepdims=True) < 0, -V, V)
        for u in range(out.shape[0]):
            c, *_ = np.linalg.lstsq(V[:, u].T, out[u], rcond=None)
            assert np.allclose(V[:, u].T @ c, out[u], atol=1e-9) and np.all(c >= -1e-9)
    assert inside > 30


def test_the_interpolant_is_continuous_along_paths_across_triangles_and_outside_the_hull(space):
    ps, keys, _ = space
    far = rot.multiply(keys[0], rot.from_rotvec(np.tile([1.5, -0.7, 0.4], (keys.shape[1], 1))))
    for a, b in ((keys[0], keys[7]), (keys[2], keys[11]), (keys[5], far)):
        t = np.linspace(0, 1, 801)
        path = rot.slerp(a[None], b[None], t[:, None])
        out = np.array([ps(k) for k in path])
        key_step = rot.angle(path[1:], path[:-1]).max()
        out_step = rot.angle(out[1:], out[:-1]).max()
        assert out_step < 40 * key_step  # Lipschitz-small steps: no jumps anywhere on the path
        assert out_step < np.radians(1.0)


def test_outside_the_hull_the_nearest_boundary_point_is_used(space):
    ps, keys, _ = space
    outside = 0
    for i in range(len(keys)):
        for t in (2.0, 4.0):
            key = rot.slerp(keys[(i + 5) % len(keys)], keys[i], t)  # extrapolated past sample i
            y = ps.project(key)
            if ps._tri.find_simplex(y) >= 0:
                continue
            outside += 1
            idx, w = ps.weights(key)
            assert len(idx) == 2 and np.all(w >= 0) and w.sum() == pytest.approx(1)
            assert tuple(sorted(idx)) in {tuple(sorted(e)) for e in ps._tri.convex_hull}
            # No point of any hull edge is nearer.
            a, b = ps.points[ps._tri.convex_hull[:, 0]], ps.points[ps._tri.convex_hull[:, 1]]
            s = np.linspace(0, 1, 201)[:, None, None]
            nearest = np.linalg.norm(a + s * (b - a) - y, axis=-1).min()
            assert np.linalg.norm(w @ ps.points[idx] - y) <= nearest + 1e-9
    assert outside > 5


def test_degenerate_sample_sets():
    rng = np.random.default_rng(3)
    values = rot.normalize(rng.normal(size=(4, 5, 4)))
    keys = rot.normalize(rng.normal(size=(4, 2, 4)))
    one = PoseSpace(keys[:1], values[:1])
    assert rot.angle(one(keys[3]), values[0]).max() < 1e-12
    # Two samples: a line; half way between the keys is half way between the values.
    two = PoseSpace(keys[:2], values[:2])
    mid = two(rot.slerp(keys[0], keys[1], 0.5))
    idx, w = two.weights(rot.slerp(keys[0], keys[1], 0.5))
    assert len(idx) == 2 and np.all(w > 0.2)
    assert rot.angle(two(keys[1]), values[1]).max() < 1e-12
    assert np.all(np.isfinite(mid))
    # Repeated keys with different values are merged into their blend.
    dup = PoseSpace(keys[[0, 0, 1, 2]], values[[0, 1, 2, 3]])
    assert len(dup.points) == 3
    assert rot.angle(dup(keys[0]), rot.slerp(values[0], values[1], 0.5)).max() < 1e-12
    with pytest.raises(RigError, match="same s"):
        PoseSpace(keys[:2], values[:3])
    with pytest.raises(RigError, match="key pose"):
        two(keys[0, :1])
