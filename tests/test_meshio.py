"""geodesics.meshio: mesh files in and out with the file's numbering (round trips through every format,
hand-written files with known index order, and malformed files, each a MeshError naming the file)."""

import json
import os
import subprocess
import sys
import warnings

import numpy as np
import pytest
import trimesh
from hypothesis import example, given, settings
from hypothesis import strategies as st

from geodesics import MeshError, MeshWarning, TriMesh, load_mesh, save_mesh
from geodesics.primitives import grid_plane, icosphere, torus
from solver.objects import mug

MESHES = {
    "mug": mug(),
    "icosphere": icosphere(2),
    "torus": torus(n_major=12, n_minor=8),
    "open grid": grid_plane(6, 5, jitter=0.2, seed=3),
}
EXACT = ["obj", "off", "ply"]
FLOAT32 = ["gltf", "glb"]


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal float64 arrays, bit for bit (tells -0.0 from 0.0)."""
    return a.shape == b.shape and np.array_equal(a.view(np.int64), b.view(np.int64))


def write(path, content) -> str:
    with open(path, "wb") as f:
        f.write(content.encode() if isinstance(content, str) else content)
    return str(path)


def fails(path, match: str, **kwargs) -> MeshError:
    """load_mesh must raise a MeshError that names the file and matches ``match``."""
    with pytest.raises(MeshError, match=match) as info:
        load_mesh(path, **kwargs)
    assert str(path) in str(info.value)
    return info.value


# ------------------------------------------------------------------------------------------ round trips


@pytest.mark.parametrize("name", MESHES)
@pytest.mark.parametrize("kind", EXACT)
def test_round_trip_is_exact_for_obj_off_ply(tmp_path, kind, name):
    mesh = MESHES[name]
    path = tmp_path / f"mesh.{kind}"
    save_mesh(mesh, path)
    back = load_mesh(path)
    assert same_bits(back.vertices, mesh.vertices)
    assert np.array_equal(back.faces, mesh.faces)
    assert back.topology_hash == mesh.topology_hash


@pytest.mark.parametrize("name", MESHES)
@pytest.mark.parametrize("kind", FLOAT32)
def test_round_trip_of_gltf_keeps_indices_and_rounds_to_float32(tmp_path, kind, name):
    mesh = MESHES[name]
    path = tmp_path / f"mesh.{kind}"
    save_mesh(mesh, path)
    back = load_mesh(path)
    assert np.array_equal(back.vertices, mesh.vertices.astype(np.float32).astype(np.float64))
    assert np.array_equal(back.faces, mesh.faces)


@pytest.mark.parametrize("name", MESHES)
def test_stl_round_trip_with_merge_keeps_faces_and_float32_corners(tmp_path, name):
    mesh = MESHES[name]
    path = tmp_path / "mesh.stl"
    save_mesh(mesh, path)
    back = load_mesh(path, merge=True)
    assert np.array_equal(back.vertices[back.faces], mesh.vertices[mesh.faces].astype(np.float32))
    # Same connectivity up to a renumbering of the vertices: first use along the faces.
    relabel = np.full(mesh.n_vertices, -1)
    relabel[mesh.faces.ravel()] = back.faces.ravel()
    assert np.array_equal(relabel[mesh.faces], back.faces)
    assert np.array_equal(np.sort(relabel), np.arange(mesh.n_vertices))
    _, first = np.unique(mesh.faces.ravel(), return_index=True)
    assert np.array_equal(relabel[mesh.faces.ravel()[np.sort(first)]], np.arange(mesh.n_vertices))


def test_stl_without_merge_is_refused_with_a_hint(tmp_path):
    path = tmp_path / "mesh.stl"
    save_mesh(MESHES["icosphere"], path)
    fails(path, r"merge=True")


@settings(max_examples=30, deadline=None)
@given(exponent=st.integers(-60, 60), seed=st.integers(0, 2**32 - 1), kind=st.sampled_from(EXACT))
def test_text_and_ply_round_trip_every_float64_exactly(tmp_path_factory, exponent, seed, kind):
    """Any magnitude and all 53 bits of mantissa survive OBJ, OFF and PLY, and so does -0.0."""
    base = icosphere(1)
    rng = np.random.default_rng(seed)
    V = base.vertices * 10.0**exponent * (1 + rng.random(base.vertices.shape) * 1e-3)
    V[base.vertices == 0] = -0.0
    mesh = TriMesh(V, base.faces)
    path = tmp_path_factory.mktemp("floats") / f"mesh.{kind}"
    save_mesh(mesh, path)
    assert same_bits(load_mesh(path).vertices, mesh.vertices)


def test_unused_vertices_survive_obj_off_ply_and_glb(tmp_path):
    V = np.array([[0.0, 0, 0], [1, 0, 0], [9, 9, 9], [0, 1, 0], [7, 7, 7]])
    with pytest.warns(MeshWarning):
        mesh = TriMesh(V, [[0, 1, 3]])
    for kind in [*EXACT, "glb"]:
        path = tmp_path / f"mesh.{kind}"
        save_mesh(mesh, path)
        with pytest.warns(MeshWarning):
            back = load_mesh(path)
        assert np.array_equal(back.vertices, V), kind
        assert np.array_equal(back.faces, [[0, 1, 3]]), kind


def test_file_type_overrides_the_extension_and_save_replaces_atomically(tmp_path):
    mesh = MESHES["icosphere"]
    path = tmp_path / "mesh.data"
    save_mesh(mesh, path, file_type="ply")
    assert load_mesh(path, ".PLY").n_faces == mesh.n_faces
    save_mesh(MESHES["torus"], path, file_type="ply")  # over an existing file
    assert load_mesh(path, "ply").n_faces == MESHES["torus"].n_faces
    assert sorted(os.listdir(tmp_path)) == ["mesh.data"]  # no temporary file left behind
    with pytest.raises(MeshError, match="unknown mesh file type 'fbx'"):
        save_mesh(mesh, tmp_path / "mesh.fbx", file_type="fbx")
    with pytest.raises(MeshError, match=r"mesh\.abc.*unknown mesh extension '\.abc'"):
        save_mesh(mesh, tmp_path / "mesh.abc")
    assert sorted(os.listdir(tmp_path)) == ["mesh.data"]


def test_importing_geodesics_does_not_import_trimesh():
    """Blender's extension does not ship trimesh: only STL and glTF need it, when they are used."""
    code = "import sys, geodesics; assert 'trimesh' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True)


# ------------------------------------------------------------------------------ files with known order

POLYGON_V = np.array(
    [
        [0.0, 0, 0],
        [1, 0, 0],
        [2, 0, 0],
        [0, 1, 0],
        [1, 1, 0.1],
        [2, 1, 0],
        [0, 2, 0],
        [1, 2, 0],
        [2.5, 2.5, 0.2],
        [2, 2, 0],
    ]
)
#: A non-convex pentagon, quads and triangles, not sorted by size (trimesh would list the triangles
#: first, then the quads' first halves, then their second halves).
POLYGONS = [[4, 5, 9, 8, 7], [0, 1, 4, 3], [1, 2, 5], [1, 5, 4], [3, 4, 7, 6]]


def polygon_mesh() -> TriMesh:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MeshWarning)
        return TriMesh.from_polygons(POLYGON_V, POLYGONS)


HAND_OBJ = """# written by hand: uv and normals differ per corner, sections, a continuation, negative indices
mtllib missing.mtl
o first
v 0 0 0
v 1 0 0
v 2 0 0
v 0 1 0
v 1 1 0.1
v 2 1 0
vt 0 0
vt 1 0
vt 0 1
vn 0 0 1
vn 0 0 -1
usemtl red
s 1
f 5/1/1 6/2/1 \\
  10/3/1 9/1/1 8/2/2
g second
usemtl blue
f 1/1/1 2/2/2 5/3/1 4/1/2
v 0 2 0
v 1 2 0
v 2.5 2.5 0.2
v 2 2 0   # after the faces that use it
o third
usemtl red
f 2//1 3//2 6//1
f -9 -5 -6
f 4/3 5/1 8/2 7/3
"""


def test_hand_written_obj_keeps_the_files_numbering(tmp_path):
    """Vertices as the ``v`` lines, faces polygon by polygon across sections, whatever uv and normals the
    corners carry (trimesh's OBJ reader splits, reorders and drops vertices of this file)."""
    mesh = load_mesh(write(tmp_path / "hand.obj", HAND_OBJ))
    expected = polygon_mesh()
    assert np.array_equal(mesh.vertices, POLYGON_V)
    assert np.array_equal(mesh.faces, expected.faces)
    assert np.array_equal(mesh.triangle_polygon, [0, 0, 0, 1, 1, 2, 3, 4, 4])
    assert np.array_equal(mesh.triangle_corners, expected.triangle_corners)


def test_a_byte_order_mark_is_read_past(tmp_path):
    """Windows editors write a UTF-8 byte-order mark before the first line: the first vertex was then an
    unknown record, skipped, and the faces pointed past the last vertex."""
    bom, text = "\ufeff", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 2 4 3\nf 1 2 3\n"
    obj = load_mesh(write(tmp_path / "bom.obj", bom + text))
    assert np.array_equal(obj.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    assert np.array_equal(obj.faces, [[1, 3, 2], [0, 1, 2]])
    off = load_mesh(write(tmp_path / "bom.off", bom + HAND_OFF))
    assert np.array_equal(off.faces, load_mesh(write(tmp_path / "plain.off", HAND_OFF)).faces)


def test_hand_written_obj_of_triangles_is_read_as_is(tmp_path):
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 2 4 3\nf 1 2 3\n"
    mesh = load_mesh(write(tmp_path / "tris.obj", text))
    assert np.array_equal(mesh.faces, [[1, 3, 2], [0, 1, 2]])
    assert mesh.triangle_polygon is None


def test_obj_with_repeated_vertices_merges_on_request(tmp_path):
    """Two triangles that repeat their shared edge's vertices: apart without merge, joined with it,
    numbered by first occurrence."""
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 4 5 6\n"
    path = write(tmp_path / "split.obj", text)
    apart = load_mesh(path)
    assert apart.n_components == 2
    joined = load_mesh(path, merge=True)
    assert np.array_equal(joined.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    assert np.array_equal(joined.faces, [[0, 1, 2], [1, 3, 2]])
    assert joined.n_components == 1


HAND_OFF = """OFF
# a comment line
10 5 0
0 0 0
1 0 0
2 0 0
0 1 0
1 1 0.1
2 1 0
0 2 0
1 2 0
2.5 2.5 0.2
2 2 0
5 4 5 9 8 7
4 0 1 4 3   255 0 0
3 1 2 5
3 1 5 4
4 3 4 7 6
"""


def test_hand_written_off_keeps_the_files_numbering(tmp_path):
    mesh = load_mesh(write(tmp_path / "hand.off", HAND_OFF))
    assert np.array_equal(mesh.vertices, POLYGON_V)
    assert np.array_equal(mesh.faces, polygon_mesh().faces)
    one_line = HAND_OFF.replace("OFF\n# a comment line\n10 5 0", "OFF 10 5 0")
    assert np.array_equal(load_mesh(write(tmp_path / "one.off", one_line)).faces, mesh.faces)
    colored = HAND_OFF.replace("OFF", "COFF").replace("\n0 2 0\n", "\n0 2 0 1 0.5 0 1\n")
    assert np.array_equal(load_mesh(write(tmp_path / "c.off", colored)).vertices, POLYGON_V)


def ply_header(fmt: str, vertex_props: str, face_props: str, n_faces: int, extra: str = "", n=10) -> str:
    return (
        f"ply\nformat {fmt} 1.0\ncomment by hand\nelement vertex {n}\n{vertex_props}"
        f"element face {n_faces}\n{face_props}{extra}end_header\n"
    )


def test_hand_written_ascii_ply_keeps_the_files_numbering(tmp_path):
    header = ply_header(
        "ascii",
        "property float x\nproperty double y\nproperty double z\nproperty uchar red\n",
        "property uchar flags\nproperty list uchar int vertex_indices\n",
        len(POLYGONS),
        "element edge 1\nproperty int vertex1\nproperty int vertex2\n",
    )
    body = "".join(f"{x} {y} {z} 200\n" for x, y, z in POLYGON_V.tolist())
    body += "".join(f"7 {len(p)} {' '.join(map(str, p))}\n" for p in POLYGONS) + "0 1\n"
    mesh = load_mesh(write(tmp_path / "hand.ply", header + body))
    assert np.array_equal(mesh.vertices, POLYGON_V)
    assert np.array_equal(mesh.faces, polygon_mesh().faces)


@pytest.mark.parametrize("fmt", ["binary_little_endian", "binary_big_endian"])
def test_binary_ply_with_polygons_of_different_sizes(tmp_path, fmt):
    """Blender's PLY export: binary, triangles, quads and ngons mixed (trimesh cannot read these)."""
    e = "<" if fmt == "binary_little_endian" else ">"
    header = ply_header(
        fmt,
        "property double x\nproperty double y\nproperty double z\nproperty list uchar float uv\n",
        "property list ushort uint vertex_indices\nproperty float weight\n",
        len(POLYGONS),
    )
    body = b"".join(
        np.asarray(v, e + "f8").tobytes()
        + np.asarray(2, "u1").tobytes()
        + np.asarray([0.5, 1], e + "f4").tobytes()
        for v in POLYGON_V
    )
    body += b"".join(
        np.asarray(len(p), e + "u2").tobytes()
        + np.asarray(p, e + "u4").tobytes()
        + np.asarray(1, e + "f4").tobytes()
        for p in POLYGONS
    )
    mesh = load_mesh(write(tmp_path / "hand.ply", header.encode() + body))
    assert same_bits(mesh.vertices, POLYGON_V)
    assert np.array_equal(mesh.faces, polygon_mesh().faces)
    fails(write(tmp_path / "cut.ply", header.encode() + body[:-3]), "truncated")


# ------------------------------------------------------------------------------------------------ glTF


def test_gltf_node_transform_is_applied(tmp_path):
    mesh = MESHES["icosphere"]
    T = trimesh.transformations.compose_matrix(angles=[0.3, 0.2, 0.1], translate=[1.0, 2.0, 3.0])
    scene = trimesh.Scene()
    scene.add_geometry(trimesh.Trimesh(mesh.vertices, mesh.faces, process=False), transform=T)
    path = write(tmp_path / "moved.glb", scene.export(file_type="glb"))
    back = load_mesh(path)
    V32 = mesh.vertices.astype(np.float32).astype(np.float64)
    np.testing.assert_allclose(back.vertices, V32 @ T[:3, :3].T + T[:3, 3], rtol=0, atol=1e-6)
    assert np.array_equal(back.faces, mesh.faces)


def test_gltf_with_several_meshes_is_refused_naming_them(tmp_path):
    scene = trimesh.Scene()
    for name, mesh in [("cup", MESHES["mug"]), ("ball", MESHES["icosphere"])]:
        scene.add_geometry(trimesh.Trimesh(mesh.vertices, mesh.faces, process=False), geom_name=name)
    path = write(tmp_path / "two.glb", scene.export(file_type="glb"))
    fails(path, r"2 geometries \('cup' \(Trimesh\), 'ball' \(Trimesh\)\).*join them")


def test_gltf_mesh_placed_twice_is_refused(tmp_path):
    mesh = trimesh.Trimesh(MESHES["icosphere"].vertices, MESHES["icosphere"].faces, process=False)
    scene = trimesh.Scene()
    scene.add_geometry(mesh, geom_name="ball", node_name="a")
    scene.graph.update(frame_to="b", geometry="ball", matrix=np.eye(4) + np.eye(4, k=3))  # an instance
    path = write(tmp_path / "twice.glb", scene.export(file_type="glb"))
    fails(path, r"places its mesh 'ball' 2 times")


def test_gltf_point_cloud_is_refused(tmp_path):
    cloud = trimesh.PointCloud(np.random.default_rng(1).random((20, 3)))
    path = write(tmp_path / "cloud.glb", trimesh.Scene(cloud).export(file_type="glb"))
    fails(path, r"PointCloud of 20 points, not a mesh")


# -------------------------------------------------------------------------------------- malformed files

ALL = ["obj", "off", "ply", "stl", "gltf", "glb"]


def saved(tmp_path, kind: str) -> bytes:
    path = tmp_path / f"good.{kind}"
    save_mesh(MESHES["icosphere"], path)
    return path.read_bytes()


@pytest.mark.parametrize("kind", ALL)
def test_truncated_files(tmp_path, kind):
    data = saved(tmp_path, kind)
    path = write(tmp_path / f"cut.{kind}", data[: len(data) // 2])
    fails(path, "truncated|no faces|needs|outside|complete|malformed|cannot read", merge=True)


@pytest.mark.parametrize("kind", ALL)
def test_garbage_files(tmp_path, kind):
    path = write(tmp_path / f"garbage.{kind}", np.random.default_rng(7).bytes(2000))
    fails(path, "binary data|not a PLY|complete|malformed|header", merge=True)


@pytest.mark.parametrize("kind", ALL)
def test_empty_files(tmp_path, kind):
    fails(write(tmp_path / f"empty.{kind}", b""), "empty")
    fails(write(tmp_path / f"blank.{kind}", b"\n \n"), "empty|complete|malformed|cannot read", merge=True)


def test_missing_file_directory_and_unknown_types(tmp_path):
    fails(tmp_path / "nowhere.obj", "no such file")
    (tmp_path / "folder.obj").mkdir()
    fails(tmp_path / "folder.obj", "directory")
    path = write(tmp_path / "mesh.fbx", "whatever")
    fails(path, r"unknown mesh extension '\.fbx'; use one of \.obj, \.ply")
    fails(path, "unknown mesh file type 'dae'", file_type="dae")
    fails(write(tmp_path / "mesh", "v 0 0 0"), "unknown mesh extension ''")


XYZ = "property float x\nproperty float y\nproperty float z\n"
NAN_FILES = {
    "obj": "v 0 0 0\nv 1 nan 0\nv 0 1 0\nf 1 2 3\n",
    "off": "OFF\n3 1 0\n0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n",
    "ply": ply_header("ascii", XYZ, "property list uchar int vertex_indices\n", 1, n=3)
    + "0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n",
}


@pytest.mark.parametrize("kind", NAN_FILES)
def test_nan_coordinates(tmp_path, kind):
    err = fails(write(tmp_path / f"nan.{kind}", NAN_FILES[kind]), "vertices 1 have NaN")
    assert list(err.vertices) == [1]


@pytest.mark.parametrize("kind", NAN_FILES)
def test_out_of_range_indices(tmp_path, kind):
    text = NAN_FILES[kind].replace("nan", "0.5")
    text = text.replace("f 1 2 3", "f 1 2 4").replace("3 0 1 2", "3 0 1 3")
    fails(write(tmp_path / f"range.{kind}", text), r"outside 0\.\.2")


def test_obj_errors_name_the_line(tmp_path):
    fails(write(tmp_path / "a.obj", "v 0 0 0\nv 1 0\n"), "line 2: a vertex needs three numbers")
    fails(
        write(tmp_path / "b.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n"), "line 4: a face needs at least three"
    )
    fails(write(tmp_path / "c.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n"), "line 4: vertex index 0")
    fails(
        write(tmp_path / "d.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 x 2\n"),
        "line 4: unreadable face corner 'x'",
    )


def test_point_clouds_and_meshless_files(tmp_path):
    fails(write(tmp_path / "cloud.obj", "v 0 0 0\nv 1 0 0\n"), "2 vertices but no faces")
    header = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
    fails(write(tmp_path / "cloud.ply", header + "end_header\n0 0 0\n1 0 0\n"), "2 vertices but no faces")
    fails(write(tmp_path / "nothing.obj", "# only a comment\no empty\n"), "no vertices and no faces")
    fails(write(tmp_path / "bad.off", "OFF\n3 1\n0 0 0\n1 0 0\n0 1 0\n4 0 1 2\n"), "as many indices")
    fails(write(tmp_path / "bad.ply", header.replace("float z", "float q") + "end_header\n"), "no x, y and z")
    fails(write(tmp_path / "head.ply", header), "no end_header")
    fails(write(tmp_path / "type.ply", header.replace("float z", "quad z") + "end_header\n"), "header line")


def test_mesh_errors_keep_the_offending_elements(tmp_path):
    """A non-manifold file: TriMesh's error, prefixed with the path, with its edges and faces."""
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nf 1 2 3\nf 2 1 4\nf 1 2 5\n"
    err = fails(write(tmp_path / "fin.obj", text), "non-manifold")
    assert err.edges.tolist() == [[0, 1]]
    assert sorted(err.faces) == [0, 1, 2]


def test_gltf_json_is_checked(tmp_path):
    good = json.loads(saved(tmp_path, "gltf"))
    good["accessors"][0]["bufferView"] = 99
    fails(write(tmp_path / "broken.gltf", json.dumps(good)), "trimesh cannot read it as GLTF")


GOOD: dict[str, bytes] = {}


def good_file(tmp_path_factory, kind: str) -> bytes:
    if kind not in GOOD:
        path = tmp_path_factory.mktemp("good") / f"mesh.{kind}"
        save_mesh(MESHES["torus"], path)
        GOOD[kind] = path.read_bytes()
    return GOOD[kind]


@settings(max_examples=60, deadline=None)
@given(
    kind=st.sampled_from(ALL),
    cut=st.floats(0, 1),
    flips=st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), max_size=4),
)
@example(kind="ply", cut=1.0, flips=[(1.0, 1)])  # the last face's last index out of range, with merge
def test_damaged_files_load_or_raise_mesh_errors(tmp_path_factory, kind, cut, flips):
    """Any prefix of a good file, with any bytes changed, either loads or raises a MeshError naming it."""
    data = bytearray(good_file(tmp_path_factory, kind))
    for where, value in flips:
        data[int(where * (len(data) - 1))] = value
    path = tmp_path_factory.mktemp("damaged") / f"mesh.{kind}"
    write(path, bytes(data[: int(cut * len(data))]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            load_mesh(path, merge=True)
        except MeshError as err:
            assert str(path) in str(err)


def test_ascii_ply_values_take_their_declared_type(tmp_path):
    header = (
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty double y\nproperty double z\n"
    )
    header += "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
    mesh = load_mesh(write(tmp_path / "types.ply", header + "0.1 0 0.1\n1 0.1 0\n0 1 0.3\n3 0 1 2\n"))
    assert mesh.vertices[0, 0] == np.float32(0.1) and mesh.vertices[0, 2] == 0.1
    fails(write(tmp_path / "half.ply", header + "0 0 0\n1 0 0\n0 1 0\n3 0 1.5 2\n"), "non-integer")
    fails(write(tmp_path / "neg.ply", header.replace("face 1", "face -1")), "header line 'element face -1'")


# MeshLab's ASCII PLY, laid out as trimesh's models/fuze_ascii.ply (mikedh/trimesh): its header verbatim
# but for the counts, its first 7 vertex lines and the first 5 face lines (which use only those vertices),
# each line with its trailing space. Every face line holds 21 values where the header declares 15 (list of
# 3 indices, list of 6 texcoords, 4 colours): MeshLab writes 6 more that trimesh and geometry-central's
# happly, which read a line per record, ignore.
FUZE_HEADER = (
    "ply\nformat ascii 1.0\ncomment VCGLIB generated\ncomment TextureFile fuze uv.jpg\nelement vertex 7\n"
    "property float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\n"
    "property uchar blue\nproperty uchar alpha\nelement face 5\nproperty list uchar int vertex_indices\n"
    "property list uchar float texcoord\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
    "property uchar alpha\nend_header\n"
)
FUZE_VERTICES = [
    "0.002047 -0.002871 0.004031 192 192 192 255 ",
    "0.002047 0.006546 0.004031 192 192 192 255 ",
    "0.013817 -0.007579 0.004031 192 192 192 255 ",
    "0.011463 0.001838 0.004031 192 192 192 255 ",
    "0.011463 0.011254 0.004031 192 192 192 255 ",
    "-0.008547 0.000661 0.004031 192 192 192 255 ",
    "-0.009724 -0.007579 0.004031 192 192 192 255 ",
]
FUZE_FACES = [
    "3 0 5 1 6 0.629012 0.417026 0.599829 0.426753 0.629012 0.442966 9 1 1 1 1 1 1 1 1 1 ",
    "3 0 6 5 6 0.629012 0.417026 0.596587 0.404056 0.599829 0.426753 9 1 1 1 1 1 1 1 1 1 ",
    "3 2 0 3 6 0.661437 0.404056 0.629012 0.417026 0.654952 0.429996 9 1 1 1 1 1 1 1 1 1 ",
    "3 3 0 1 6 0.654952 0.429996 0.629012 0.417026 0.629012 0.442966 9 1 1 1 1 1 1 1 1 1 ",
    "3 3 1 4 6 0.654952 0.429996 0.629012 0.442966 0.654952 0.455936 9 1 1 1 1 1 1 1 1 1 ",
]


def fuze(vertices=FUZE_VERTICES, faces=FUZE_FACES) -> str:
    return FUZE_HEADER + "".join(line + "\n" for line in vertices + faces)


def test_meshlab_ascii_ply_with_undeclared_values_after_each_face(tmp_path):
    """Each record is its line: the declared properties are read, MeshLab's extra values ignored."""
    assert all(len(line.split()) == 4 + 7 + 4 + 6 for line in FUZE_FACES)  # 6 undeclared values a line
    mesh = load_mesh(write(tmp_path / "fuze.ply", fuze()))
    declared = np.array([line.split()[:3] for line in FUZE_VERTICES], np.float32)  # "property float"
    assert np.array_equal(mesh.vertices, declared.astype(np.float64))
    assert mesh.faces.tolist() == [[int(i) for i in line.split()[1:4]] for line in FUZE_FACES]
    # Windows line ends and blank lines before a record (happly skips them) read the same
    crlf = fuze(FUZE_VERTICES, ["", *FUZE_FACES]).replace("\n", "\r\n")
    assert np.array_equal(load_mesh(write(tmp_path / "crlf.ply", crlf)).faces, mesh.faces)


def test_ascii_ply_lines_too_short_for_their_properties_name_element_and_line(tmp_path):
    """A record cut short, or carried on over two lines, is an error naming the element and the line."""
    short = [*FUZE_FACES[:2], "3 2 0 3 6 0.661437 0.404056 0.629012", *FUZE_FACES[3:]]
    fails(write(tmp_path / "short.ply", fuze(faces=short)), r"PLY face element's line 30 holds 8 values")
    split = [*FUZE_VERTICES[:3], "0.011463 0.001838", "0.004031 192 192 192 255", *FUZE_VERTICES[4:]]
    fails(write(tmp_path / "split.ply", fuze(split)), r"PLY vertex element's line 24 holds 2 values")
    text = fuze(faces=[*FUZE_FACES[:4], "3 3 1 x 6 0.65 0.42 0.62 0.44 0.65 0.45 9 1 1 1"])
    fails(
        write(tmp_path / "word.ply", text),
        r"face element holds a value that is not a number, 'x', on line 32",
    )
    lists = fuze(faces=[*FUZE_FACES[:1], "-3 0 6 5", *FUZE_FACES[2:]])
    fails(
        write(tmp_path / "negative.ply", lists),
        r"face element's line 29 holds a list length that is negative",
    )
    fails(write(tmp_path / "cut.ply", fuze(faces=FUZE_FACES[:4])), "truncated: its face element ends early")


@settings(max_examples=60, deadline=None)
@given(cut=st.floats(0, 1), flips=st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), max_size=4))
def test_damaged_ascii_ply_loads_or_raises_mesh_errors(tmp_path_factory, cut, flips):
    """The line reader too: any prefix of MeshLab's layout, any bytes changed, loads or raises a MeshError."""
    data = bytearray(fuze().encode())
    for where, value in flips:
        data[int(where * (len(data) - 1))] = value
    path = tmp_path_factory.mktemp("damaged") / "fuze.ply"
    write(path, bytes(data[: int(cut * len(data))]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            load_mesh(path)
        except MeshError as err:
            assert str(path) in str(err)


def test_without_trimesh_stl_and_gltf_raise_mesh_errors(tmp_path, monkeypatch):
    path = tmp_path / "mesh.stl"
    save_mesh(MESHES["icosphere"], path)
    monkeypatch.setitem(sys.modules, "trimesh", None)  # import trimesh now raises ImportError
    fails(path, r"through trimesh, which is not installed", merge=True)
    with pytest.raises(MeshError, match=r"mesh\.glb: GLB files are read and written through trimesh"):
        save_mesh(MESHES["icosphere"], tmp_path / "mesh.glb")
    save_mesh(MESHES["icosphere"], tmp_path / "mesh.obj")  # OBJ, PLY and OFF do not need it
    assert load_mesh(tmp_path / "mesh.obj").n_faces == MESHES["icosphere"].n_faces
    with pytest.raises(TypeError, match="needs a TriMesh"):
        save_mesh(MESHES["icosphere"].vertices, tmp_path / "mesh.obj")
