"""Metrics of §4.2: distances, intersection volumes (penetration, clusters, hulls), self-intersection,
plots."""

import pickle
import struct
import sys

import numpy as np
import pytest

from geodesics import TriMesh
from solver import SolverError, hands, objects
from solver.retarget.metrics import (
    IntersectionMeter,
    Intersections,
    cluster_volumes,
    intersection_volume,
    mean_distances,
    mesh_volume,
    plot_metrics,
    ray_winding,
    self_penetrating,
    vertex_clusters,
)


@pytest.fixture(scope="module")
def human():
    return hands.make_hand("human")


def _winding_oracle(V, faces, p):
    """Generalized winding number of a closed mesh at p: summed solid angles (Van Oosterom-Strackee)."""
    a, b, c = (V[faces[:, k]] - p for k in range(3))
    la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
    det = np.einsum("ij,ij->i", a, np.cross(b, c))
    den = (
        la * lb * lc
        + np.einsum("ij,ij->i", a, b) * lc
        + np.einsum("ij,ij->i", b, c) * la
        + np.einsum("ij,ij->i", c, a) * lb
    )
    return 2 * np.arctan2(det, den).sum() / (4 * np.pi)


# ------------------------------------------------------------------------------------ distances


def test_mean_distances_per_frame():
    positions = np.zeros((5, 3))
    targets = np.array([[3.0, 4, 0], [0, 0, 1], [0, 2, 0], [0, 0, 6], [1, 0, 0]])
    d = mean_distances(positions, targets, [0, 1, 3, 3, 5])
    np.testing.assert_allclose(d[[0, 1, 3]], [5.0, 1.5, 3.5])
    assert np.isnan(d[2])  # a frame without points
    with pytest.raises(SolverError, match="offsets"):
        mean_distances(positions, targets, [0, 3, 2, 5])


# ------------------------------------------------------------------------------------ volumes and clusters


def test_hull_volumes_of_known_solids():
    tet = np.array([[0.0, 0, 0], [2, 0, 0], [0, 3, 0], [0, 0, 4]])
    cube = 0.5 * np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], float) + 10
    flat = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]) - 10
    pair = np.array([[5.0, 5, 5], [6, 5, 5]])
    pts = np.concatenate([tet, cube, flat, pair])
    labels = np.repeat([0, 1, 2, 3], [4, 8, 4, 2])
    np.testing.assert_allclose(cluster_volumes(pts, labels), [4.0, 0.125, 0.0, 0.0], rtol=1e-12)
    # Vertices outside every cluster (-1) are ignored.
    np.testing.assert_allclose(cluster_volumes(pts, np.where(labels == 1, 0, -1)), [0.125])


def test_mesh_volume_and_a_whole_penetrating_mesh():
    box = objects.box((0.2, 0.3, 0.5), cells=3)
    assert mesh_volume(box.vertices, box.faces) == pytest.approx(0.03, rel=1e-12)
    frames = np.stack([box.vertices, 2 * box.vertices])
    np.testing.assert_allclose(mesh_volume(frames, box.faces), [0.03, 0.24], rtol=1e-12)
    everything = np.ones(box.n_vertices, bool)
    assert intersection_volume(box.vertices, box.faces, everything) == pytest.approx(100.0, rel=1e-9)
    assert intersection_volume(box.vertices, box.faces, ~everything) == 0.0


def test_clusters_are_connected_components_on_the_mesh():
    box = objects.box((1.0, 1.0, 1.0), cells=4)
    V = box.vertices
    top = V[:, 2] > 0.49
    corner = (V[:, 2] < -0.49) & (V[:, 0] < -0.2) & (V[:, 1] < -0.2)
    labels = vertex_clusters(box.faces, box.n_vertices, top | corner)
    assert set(labels[top]) == {labels[top][0]} and set(labels[corner]) == {labels[corner][0]}
    assert labels[top][0] != labels[corner][0] and (labels[~(top | corner)] == -1).all()
    assert labels.max() == 1
    # The top face's 25 vertices are flat (volume 0); the corner cluster too.
    assert cluster_volumes(V, labels).tolist() == [0.0, 0.0]


# ------------------------------------------------------------------------------------ ray casting


def test_ray_winding_is_exact_through_edges_and_vertices():
    """Axis-aligned rays through a grid-meshed box hit its edges and vertices exactly: ties must still
    give winding 1 inside and 0 outside."""
    box = objects.box((1.0, 1.0, 1.0), cells=4)
    g = np.linspace(-0.5, 0.5, 9)
    P = np.array([[x, y, z] for x in g for y in g for z in (-0.3, 0.0, 0.2, 0.7, -0.9)])
    inside = (np.abs(P[:, :2]).max(1) < 0.5) & (np.abs(P[:, 2]) < 0.5)
    on_side = (np.abs(P[:, :2]).max(1) == 0.5) & (np.abs(P[:, 2]) < 0.5)
    for signs in (np.ones(len(P)), -np.ones(len(P))):
        w = ray_winding(P, signs, np.eye(3), box.vertices, box.faces)
        np.testing.assert_array_equal(w[inside], 1)
        np.testing.assert_array_equal(w[~inside & ~on_side], 0)
        assert set(w[on_side].tolist()) <= {0, 1}  # on the surface itself: either side is right


def test_ray_winding_counts_overlaps_twice():
    a = objects.sphere(1.0, 2)
    V = np.concatenate([a.vertices, a.vertices + np.array([0.8, 0.0, 0.0])])
    F = np.concatenate([a.faces, a.faces + a.n_vertices])
    P = np.array([[0.4, 0.0, 0.0], [-0.6, 0.0, 0.0], [1.4, 0.1, 0.0], [3.0, 0.0, 0.0]])
    frame = np.linalg.qr(np.random.default_rng(1).standard_normal((3, 3)))[0]
    frame *= np.sign(np.linalg.det(frame))
    w = ray_winding(P, np.ones(4), frame, V, F)
    np.testing.assert_array_equal(w, [2, 1, 1, 0])
    assert [round(_winding_oracle(V, F, p)) for p in P] == [2, 1, 1, 0]


def test_self_penetration_matches_winding_numbers(human):
    theta = human.rig.rest.copy()
    theta[human.flexion_dofs("index")] = np.radians([150.0, 150.0, 120.0])  # through the palm, folded
    V = human.posed_vertices(theta)
    f = human.mesh.faces
    flagged = self_penetrating(V, f)
    rng = np.random.default_rng(0)
    sample = np.union1d(np.flatnonzero(flagged), rng.choice(len(V), 300, replace=False))
    a, b, c = (V[f[:, k]] for k in range(3))
    N = np.zeros_like(V)
    for k in range(3):
        np.add.at(N, f[:, k], np.cross(b - a, c - a))
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    oracle = np.array([_winding_oracle(V, f, V[i] + 1e-6 * N[i]) for i in sample])
    np.testing.assert_array_equal(flagged[sample], oracle > 0.5)
    assert (oracle > 1.5).any()  # some vertices sit inside two overlapping parts: parity would fail


def test_self_intersection_of_rest_and_bent_hands(human):
    meter = IntersectionMeter(human.mesh)
    rest = meter.frame(human.posed_vertices(human.rig.rest))
    # The procedural hand's thumb base overlaps the palm a little (13 vertices): about 0.01 %.
    assert rest.self_intersection < 0.05 and rest.hand_object == 0 and rest.table == 0
    theta = human.rig.rest.copy()
    theta[human.flexion_dofs("index")] = np.radians([150.0, 150.0, 120.0])
    bent = meter.frame(human.posed_vertices(theta))
    assert bent.self_intersection > 1.0 and bent.self_vertices.sum() > 10 * rest.self_vertices.sum()


# ------------------------------------------------------------------------------------ intersection volumes


def test_sphere_sunk_into_a_table_approaches_the_cap_volume():
    r, h = 0.04, 0.012
    cap = np.pi * h * h * (3 * r - h) / 3
    table = np.eye(4)
    table[2, 3] = -0.05  # top face at z = 0
    board = objects.box((0.5, 0.5, 0.1), cells=2)
    errors = []
    for sub in (2, 3, 4):
        ball = objects.sphere(r, sub)
        V = ball.vertices + np.array([0.0, 0.0, r - h])
        by_table = IntersectionMeter(ball, table=table, table_size=[0.5, 0.5, 0.1]).frame(V)
        by_object = IntersectionMeter(ball, object_mesh=board).frame(V, table)
        assert by_object.hand_object == pytest.approx(by_table.table, rel=1e-12)  # SDF sign = box test
        assert by_table.self_intersection == 0 and by_table.hand_object == 0
        errors.append(abs(by_table.table / 100 * mesh_volume(V, ball.faces) - cap) / cap)
    assert errors[0] > errors[1] > errors[2] and errors[2] < 0.02  # 31 %, 4.1 %, 1.4 %


def test_no_intersection_is_zero(human):
    ball = objects.sphere(0.03, 2)
    table = np.eye(4)
    table[2, 3] = -0.5
    meter = IntersectionMeter(human.mesh, object_mesh=ball, table=table, table_size=[1.0, 1.0, 0.1])
    pose = np.eye(4)
    pose[:3, 3] = [0.0, 0.1, 0.2]  # the ball floats above the hand
    r = meter.frame(human.posed_vertices(human.rig.rest), pose)
    assert r.hand_object == 0.0 and r.table == 0.0
    assert not r.object_vertices.any() and not r.table_vertices.any()


def test_motion_and_pickling(human):
    ball = objects.sphere(0.03, 2)
    meter = IntersectionMeter(human.mesh, object_mesh=ball)
    V = np.stack([human.posed_vertices(human.rig.rest)] * 3)
    poses = np.tile(np.eye(4), (3, 1, 1))
    poses[:, :3, 3] = [[0.0, 0.1, 0.2], [0.0, 0.06, 0.0], [0.0, 0.06, -0.02]]  # away, sunk, deeper
    calls = []
    out = meter.motion(V, poses, progress=lambda i, n: calls.append((i, n)))
    assert calls == [(1, 3), (2, 3), (3, 3)]
    assert out.hand_object[0] == 0 and out.hand_object[1] > 0 and out.hand_volume[0] > 0
    twin = pickle.loads(pickle.dumps(meter))
    assert twin.frame(V[2], poses[2]).hand_object == meter.frame(V[2], poses[2]).hand_object


def test_open_hand_mesh_is_refused():
    plane = TriMesh(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))
    with pytest.raises(SolverError, match="closed"):
        IntersectionMeter(plane)


# ------------------------------------------------------------------------------------ plots


def _png_size(path):
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def test_plot_writes_a_png_of_the_requested_size(tmp_path):
    F = 240
    t = np.arange(F)
    marker = 0.01 + 0.002 * np.sin(t / 20)
    contact = np.where((t > 60) & (t < 180), 0.003, np.nan)
    count = np.where((t > 60) & (t < 180), 1500, 0)
    inter = Intersections(np.abs(np.sin(t / 30)), 0.1 * np.ones(F), np.zeros(F), np.ones(F))
    out = plot_metrics(
        tmp_path / "metrics.png",
        120.0,
        marker_distance=marker,
        contact_distance=contact,
        contact_count=count,
        intersections=inter,
        size=(900, 600),
        title="human -> witch",
    )
    assert out == tmp_path / "metrics.png"
    assert _png_size(out) == (900, 600)
    only = plot_metrics(tmp_path / "inter.png", 120.0, intersections=inter, size=(400, 300))
    assert _png_size(only) == (400, 300)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["inter.png", "metrics.png"]  # no temporaries
    with pytest.raises(SolverError, match="nothing to plot"):
        plot_metrics(tmp_path / "x.png", 120.0)


def test_without_matplotlib_plotting_says_how_to_get_it(tmp_path, monkeypatch):
    """matplotlib is optional (the Blender extension does not bundle it): asking for a plot without it
    names the extra to install instead of failing with an ImportError from deep inside."""
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    monkeypatch.setitem(sys.modules, "matplotlib.figure", None)
    monkeypatch.setitem(sys.modules, "matplotlib.backends.backend_agg", None)
    with pytest.raises(SolverError, match=r"pip install -e '\.\[plots\]' in the checkout"):
        plot_metrics(tmp_path / "x.png", 120.0, marker_distance=np.ones(10))
    assert not (tmp_path / "x.png").exists()
