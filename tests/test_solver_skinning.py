"""Linear blend skinning: against an independent per-vertex loop, analytic derivatives against central
finite differences, weight validation."""

import numpy as np
import pytest
from scipy import sparse

from geodesics import SurfacePoints, TriMesh
from geodesics.primitives import icosphere
from solver import Rig, SkinnedMesh, SolverError, hands, normalize_vertex_groups


@pytest.fixture(scope="module")
def tiny():
    """Four bones (a branch at bone 1, mixed Euler orders) skinning a stretched sphere."""
    heads = np.array([[0, 0, 0], [0, 1, 0], [0.1, 2, 0.2], [0.3, 1.2, 0.1]], float)
    tails = np.array([[0, 1, 0], [0.1, 2, 0.2], [0.2, 3, 0.1], [0.8, 1.5, 0.3]], float)
    rig = Rig.from_bones(
        ["a", "b", "c", "d"],
        [-1, 0, 1, 1],
        heads,
        tails,
        [[0, 0, 1]] * 4,
        rotation_modes=["XYZ", "ZXY", "YZX", "XYZ"],
    )
    sphere = icosphere(2)
    mesh = TriMesh(sphere.vertices * [0.5, 1.5, 0.5] + [0, 1.5, 0], sphere.faces)
    rng = np.random.default_rng(0)
    W = rng.random((mesh.n_vertices, 4)) ** 3
    W[W < 0.05] = 0.0  # sparse, like vertex groups
    W[np.arange(mesh.n_vertices), np.argmax(W, axis=1)] += 0.1
    return SkinnedMesh(mesh, rig, normalize_vertex_groups(W))


def per_vertex_lbs(skin: SkinnedMesh, theta) -> np.ndarray:
    """Blender's Armature modifier written out one vertex and one bone at a time."""
    rig = skin.rig
    pose = rig.pose_matrices(theta)
    W = skin.weights.toarray()
    out = np.empty_like(skin.mesh.vertices)
    for v, x in enumerate(skin.mesh.vertices):
        acc, total = np.zeros(3), 0.0
        for b in range(rig.n_bones):
            if W[v, b] > 0:
                deform = pose[b] @ np.linalg.inv(rig.matrix_local[b])
                acc += W[v, b] * (deform[:3, :3] @ x + deform[:3, 3])
                total += W[v, b]
        out[v] = acc / total if total > 0 else x
    return out


def test_lbs_matches_a_per_vertex_loop(tiny):
    rng = np.random.default_rng(1)
    for _ in range(3):
        theta = rng.normal(size=tiny.rig.n_dofs) * 0.6
        assert np.abs(tiny.posed_vertices(theta) - per_vertex_lbs(tiny, theta)).max() < 1e-13
    assert np.abs(tiny.posed_vertices(tiny.rig.rest) - tiny.mesh.vertices).max() < 1e-14


def test_posed_points_are_barycentric_and_normals_from_the_posed_triangle(tiny):
    rng = np.random.default_rng(2)
    theta = rng.normal(size=tiny.rig.n_dofs) * 0.5
    points = SurfacePoints(rng.integers(0, tiny.mesh.n_faces, 50), rng.dirichlet([1, 1, 1], 50))
    p, n = tiny.posed_points(theta, points)
    V = tiny.posed_vertices(theta)
    T = V[tiny.mesh.faces[points.faces]]
    assert np.abs(p - np.einsum("kc,kcd->kd", points.bary, T)).max() < 1e-14
    u = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    assert np.abs(n - u / np.linalg.norm(u, axis=1, keepdims=True)).max() < 1e-13


def relative_error(analytic, numeric):
    return np.abs(analytic - numeric).max() / max(np.abs(numeric).max(), 1e-300)


@pytest.mark.parametrize("skin_name", ["tiny", "human"])
def test_jacobians_match_central_differences(skin_name, tiny):
    skin = tiny if skin_name == "tiny" else hands.make_hand("human")
    rng = np.random.default_rng(3)
    rig = skin.rig
    theta = np.clip(rng.normal(size=rig.n_dofs) * 0.4, rig.lower, rig.upper)
    points = SurfacePoints(rng.integers(0, skin.mesh.n_faces, 40), rng.dirichlet([2, 2, 2], 40))
    _, _, dp, dn = skin.point_jacobian(theta, points)
    h = 1e-6 * max(1.0, float(np.abs(theta).max()))
    for j in range(rig.n_dofs):
        step = np.zeros(rig.n_dofs)
        step[j] = h
        p1, n1 = skin.posed_points(theta + step, points)
        p0, n0 = skin.posed_points(theta - step, points)
        scale = skin.size
        assert np.abs(dp[:, :, j] - (p1 - p0) / (2 * h)).max() < 1e-5 * scale, rig.dof_names[j]
        # Normals are unit vectors: compare against the scale of a rotation's effect (1 per radian).
        assert np.abs(dn[:, :, j] - (n1 - n0) / (2 * h)).max() < 1e-5, rig.dof_names[j]
    V, _ = skin.vertex_jacobian(theta, np.arange(0, skin.mesh.n_vertices, 7))
    assert np.abs(V - skin.posed_vertices(theta)[::7]).max() < 1e-14


def test_rotation_columns_are_relatively_exact(tiny):
    """Column by column, 1e-5 relative: the issue's tolerance."""
    rng = np.random.default_rng(4)
    theta = rng.normal(size=tiny.rig.n_dofs) * 0.5
    points = SurfacePoints(rng.integers(0, tiny.mesh.n_faces, 30), rng.dirichlet([2, 2, 2], 30))
    _, _, dp, dn = tiny.point_jacobian(theta, points)
    h = 1e-6
    for j in np.flatnonzero(tiny.rig.is_rotation):
        step = np.zeros(tiny.rig.n_dofs)
        step[j] = h
        p1, n1 = tiny.posed_points(theta + step, points)
        p0, n0 = tiny.posed_points(theta - step, points)
        assert relative_error(dp[:, :, j], (p1 - p0) / (2 * h)) < 1e-5
        assert relative_error(dn[:, :, j], (n1 - n0) / (2 * h)) < 1e-5


def test_vector_jacobian_product_equals_jacobian_transpose(tiny):
    rng = np.random.default_rng(5)
    theta = rng.normal(size=tiny.rig.n_dofs) * 0.5
    kin = tiny.rig.kinematics(theta)
    skin = tiny.vertex_skin()
    adjoint = rng.normal(size=(tiny.mesh.n_vertices, 3))
    expected = np.einsum("vi,vid->d", adjoint, skin.jacobian(kin))
    assert np.abs(skin.vjp(kin, adjoint) - expected).max() < 1e-12 * np.abs(expected).max()


def test_weights_are_validated_with_the_offending_vertices(tiny):
    mesh, rig = tiny.mesh, tiny.rig
    W = tiny.weights.toarray()
    unnormalized = W.copy()
    unnormalized[[5, 9]] *= 1.5
    with pytest.raises(SolverError, match=r"vertices 5, 9 do not sum to one") as err:
        SkinnedMesh(mesh, rig, unnormalized)
    assert err.value.vertices.tolist() == [5, 9]
    negative = W.copy()
    negative[7, 0] = -0.2
    with pytest.raises(SolverError, match=r"vertices 7 are negative \(e.g. vertex 7, bone 0") as err:
        SkinnedMesh(mesh, rig, negative)
    assert err.value.vertices.tolist() == [7] and err.value.bones.tolist() == [0]
    nan = W.copy()
    nan[3, 1] = np.nan
    with pytest.raises(SolverError, match="vertices 3 are NaN"):
        SkinnedMesh(mesh, rig, nan)
    with pytest.raises(SolverError, match=r"shape \(n_vertices, n_bones\)"):
        SkinnedMesh(mesh, rig, W[:, :3])
    with pytest.raises(SolverError, match="do not lie on the hand mesh"):
        tiny.posed_points(rig.rest, SurfacePoints([mesh.n_faces + 3], [[1, 0, 0]]))


def test_blender_normalization_and_unweighted_vertices(tiny):
    raw = sparse.csr_matrix(np.array([[2.0, 2.0, 0, 0], [0, 0, 0, 0], [0, 0.5, 0, 0]]))
    W = normalize_vertex_groups(raw).toarray()
    assert np.allclose(W, [[0.5, 0.5, 0, 0], [0, 0, 0, 0], [0, 1, 0, 0]])
    # A vertex no bone moves stays where it is, as in Blender.
    weights = tiny.weights.toarray()
    weights[0] = 0.0
    skin = SkinnedMesh(tiny.mesh, tiny.rig, weights)
    theta = np.full(tiny.rig.n_dofs, 0.3)
    assert np.allclose(skin.posed_vertices(theta)[0], tiny.mesh.vertices[0])
