"""The authors' rig reducer's files: libigl .dmat/.tgf, their rigs into our Skeleton and back, and our
reduction in their output files. Fixtures (tests/fixtures/rigreducer) are written by hand from the layouts
in tangible/rigreducer.py's docstring."""

import contextlib
import itertools
import shutil
import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from tangible import Kit, Skeleton, reduce
from tangible import rotations as rot
from tangible.creatures import creature
from tangible.errors import RigError
from tangible.joint import THEIR_AXES
from tangible.rigreducer import (
    TGF,
    format_dmat,
    format_tgf,
    parse_dmat,
    parse_tgf,
    read_dmat,
    read_reduction,
    read_rig,
    read_tgf,
    write_dmat,
    write_reduction,
    write_rig,
)

FIXTURES = Path(__file__).parent / "fixtures" / "rigreducer"
C45 = np.sqrt(0.5)
CASES = itertools.count()


@pytest.fixture
def rig_dir(tmp_path):
    """A scratch copy of the fixture rigs."""
    for f in FIXTURES.glob("*.*"):
        shutil.copy(f, tmp_path / f.name)
    return tmp_path


# ================================================================== .dmat


def test_dmat_layout_ascii_and_binary():
    expect = np.array([[1.0, 4.0], [2.0, 5.0], [3.0, 6.0]])  # column by column: 1 2 3 | 4 5 6
    np.testing.assert_array_equal(parse_dmat(b"2 3\n1\n2\n3\n4\n5\n6\n"), expect)
    np.testing.assert_array_equal(parse_dmat(b"2 3\n1 2 3\n  4 5\t6"), expect)  # any white space
    assert format_dmat(expect) == b"2 3\n1\n2\n3\n4\n5\n6\n"  # writeDMAT's layout
    binary = b"0 0\n2 3\n" + struct.pack("<6d", 1, 2, 3, 4, 5, 6)
    np.testing.assert_array_equal(parse_dmat(binary), expect)
    assert format_dmat(expect, binary=True) == binary
    assert parse_dmat(b"0 0\n").shape == (0, 0)
    assert parse_dmat(b"5 0\n").shape == (0, 5)
    np.testing.assert_array_equal(format_dmat([1.5, -2]), b"1 2\n1.5\n-2\n")  # a vector is a column


finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@given(
    hnp.arrays(np.float64, hnp.array_shapes(min_dims=2, max_dims=2, min_side=0, max_side=6), elements=finite)
)
@settings(max_examples=200, deadline=None)
def test_dmat_round_trip_is_exact(matrix):
    np.testing.assert_array_equal(parse_dmat(format_dmat(matrix)), matrix)
    np.testing.assert_array_equal(parse_dmat(format_dmat(matrix, binary=True)), matrix)


def test_dmat_files_and_special_values(tmp_path):
    m = np.array([[np.inf, -0.0], [np.nan, 5e-324]])
    write_dmat(tmp_path / "m.dmat", m)
    back = read_dmat(tmp_path / "m.dmat")
    np.testing.assert_array_equal(back, m)
    assert np.signbit(back[0, 1])


@pytest.mark.parametrize(
    ("data", "message"),
    [
        (b"", r"line 1 should be '<columns> <rows>'"),
        (b"3\n1 2 3\n", r"line 1 should be '<columns> <rows>'"),
        (b"-1 2\n", r"line 1 should be"),
        (b"2 2 1\n1 2 3 4\n", r"line 1 should be"),
        (
            b"2 2\n1\n2\n3\n",
            r"truncated: the header \(line 1\) announces 2 rows x 2 columns = 4 values, the file has 3",
        ),
        (b"2 2\n1\n2\n3\n4\n5\n", r"too many values"),
        (b"2 2\n1\n2\nx3\n4\n", r"line 4: 'x3' is not a number"),
        (b"1 2\n1\n1_0\n", r"line 3: '1_0' is not a number"),
        (b"1 1\n0x1p3\n", r"line 2: '0x1p3' is not a number"),
        (b"1 1\n\xff\n", r"line 2: byte 0xff is not ASCII"),
        (
            b"0 0\n2 1\n" + b"\0" * 15,
            r"binary part truncated: a 1 x 2 matrix needs 16 bytes after the header, the file has 15",
        ),
        (b"0 0\n1 1\n" + b"\0" * 9, r"binary part too long"),
        (b"0 0\nx\n", r"the binary header \(line 2\) should be"),
        (b"0 2\n1\n", r"a 2 x 0 matrix has no values, but the file goes on after line 1"),
    ],
)
def test_malformed_dmat_is_a_clear_error(data, message):
    with pytest.raises(RigError, match=r"^w\.dmat: " + message):
        parse_dmat(data, "w.dmat")


def test_missing_file_names_the_file(tmp_path):
    with pytest.raises(RigError, match=r"nope\.dmat: cannot be read"):
        read_dmat(tmp_path / "nope.dmat")


@given(st.binary(max_size=200))
@settings(max_examples=1000, deadline=None)
def test_dmat_parser_fuzz_raises_only_rig_errors(data):
    try:
        m = parse_dmat(data)
    except RigError:
        return
    assert m.ndim == 2


@given(st.data())
@settings(max_examples=500, deadline=None)
def test_dmat_parser_fuzz_on_damaged_files(data):
    """Valid files with bytes flipped, dropped or inserted: a matrix or our error, nothing else."""
    good = data.draw(
        st.sampled_from(
            [(FIXTURES / "chain-pose-0001.dmat").read_bytes(), format_dmat(np.eye(3), binary=True)]
        )
    )
    raw = bytearray(good)
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(raw)))
        op = data.draw(st.sampled_from(["flip", "drop", "insert", "cut"]))
        if op == "flip" and i < len(raw):
            raw[i] ^= 1 << data.draw(st.integers(0, 7))
        elif op == "drop" and i < len(raw):
            del raw[i]
        elif op == "insert":
            raw[i:i] = data.draw(st.binary(min_size=1, max_size=3))
        else:
            del raw[i:]
    with contextlib.suppress(RigError):
        parse_dmat(bytes(raw))


# ================================================================== .tgf


def test_tgf_layout():
    tgf = parse_tgf((FIXTURES / "fork.tgf").read_bytes())
    assert tgf.nodes.shape == (6, 3) and tgf.labels[3] == "knee_L"
    np.testing.assert_array_equal(tgf.edges, [[0, 1], [0, 2], [2, 3], [0, 4], [4, 5]])
    assert not tgf.flags.any()
    # writeTGF's layout, labels after the coordinates, flags when set; anything after a second '#' ignored.
    tgf = TGF(np.array([[0, 0, 0], [0.1, 1, 2]]), np.array([[0, 1]]), np.array([[0, 1, 0]]), ("", "a b"))
    text = format_tgf(tgf)
    assert text == "   1 0 0 0\n   2 0.10000000000000001 1 2 a b\n#\n   1    2 0 1 0\n#\n"
    back = parse_tgf(text + "1 2 3\nfaces\n")
    np.testing.assert_array_equal(back.nodes, tgf.nodes)
    assert back.labels == tgf.labels and back.pseudo.tolist() == [True]
    # libigl ignores what follows an edge's integers (a TGF edge label).
    assert parse_tgf("1 0 0 0\n2 1 0 0\n#\n1 2 1 bone label\n").flags.tolist() == [[1, 0, 0]]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("1 0 0\n", r"line 1: a node line needs an index and three coordinates"),
        ("1 0 0 0\n3 0 0 1\n", r"line 2: node index 3, expected 2"),
        ("x 0 0 0\n", r"line 1: node index 'x' is not an integer"),
        ("1 0 y 0\n", r"line 1: coordinate 'y' is not a number"),
        ("1 0 0 nan\n", r"line 1: node 1 has a non-finite coordinate"),
        ("1 0 0 0\n2 0 0 1\n#\n1\n", r"line 4: an edge line needs two node indices"),
        ("1 0 0 0\n2 0 0 1\n#\n\n1 3\n", r"line 5: edge node 3 is outside 1..2"),
        ("1 0 0 0\n2 0 0 1\n#\n2 2\n", r"line 4: edge from node 2 to itself"),
    ],
)
def test_malformed_tgf_is_a_clear_error(text, message):
    with pytest.raises(RigError, match=r"^s\.tgf: " + message):
        parse_tgf(text.encode(), "s.tgf")


@given(st.binary(max_size=200) | st.text(max_size=200).map(str.encode))
@settings(max_examples=1000, deadline=None)
def test_tgf_parser_fuzz_raises_only_rig_errors(data):
    with contextlib.suppress(RigError):
        parse_tgf(data)


@given(st.text("0123456789 .-+#\n\teE", max_size=120))
@settings(max_examples=1000, deadline=None)
def test_tgf_parser_fuzz_near_the_grammar(text):
    try:
        tgf = parse_tgf(text)
    except RigError:
        return
    assert tgf.edges.shape[1:] == (2,) and np.all(tgf.edges < len(tgf.nodes))


# ================================================================== their rigs in ours


def test_bone_mode_fixture(rig_dir):
    """chain: 3 edges along x, libigl bone weights, an 8-vertex strip mesh and three poses."""
    sk, poses, weights = read_rig(rig_dir / "chain")
    assert sk.names == ("bone0", "bone1", "bone2")
    assert sk.parents.tolist() == [-1, 0, 1]
    np.testing.assert_array_equal(sk.matrix_local[:, :3, 3], [[0, 0, 0], [1, 0, 0], [2, 0, 0]])
    np.testing.assert_allclose(sk.rest_tails, [[1, 0, 0], [2, 0, 0], [3, 0, 0]], atol=1e-15)
    # Our node weights: triangle areas times mean skin weights (by hand from the strip).
    np.testing.assert_allclose(sk.weights, [1.0, 0.5, 1.5], rtol=1e-14)
    np.testing.assert_array_equal(weights, read_dmat(rig_dir / "chain-weights.dmat"))
    identity = np.array([1.0, 0, 0, 0])
    expect = np.array(
        [
            [identity, identity, identity],
            [identity, [C45, 0, 0, C45], identity],  # 90° about z at node 2; bone 2 follows rigidly
            [identity, identity, [C45, 0, C45, 0]],  # bone 2 twisted about itself: its local y
        ]
    )
    assert rot.angle(poses, expect).max() < 1e-12


def test_node_mode_fixture(rig_dir):
    """fork: Maya joint weights (one column per node), labelled nodes, end bones added 20% beyond."""
    sk, poses, weights = read_rig(rig_dir / "fork")
    assert sk.names == (
        "spine",
        "hip_L",
        "knee_L",
        "hip_R",
        "knee_R",
        "spine.end",
        "knee_L.end",
        "knee_R.end",
    )
    assert sk.parents.tolist() == [-1, -1, 1, -1, 3, 0, 2, 4]
    np.testing.assert_allclose(sk.rest_tails[5:], [[0, 1.2, 0], [0.5, -1.2, 0], [-0.5, -1.2, 0]], atol=1e-15)
    np.testing.assert_array_equal(sk.weights, sk.lengths)  # no mesh: the length proxy
    W = read_dmat(rig_dir / "fork-weights.dmat")
    np.testing.assert_array_equal(weights, W[:, [0, 0, 2, 0, 4, 1, 3, 5]])  # each bone: its head node's
    expect = np.tile([1.0, 0, 0, 0], (1, 8, 1))
    expect[0, 2] = [C45, -C45, 0, 0]  # knee_L turned by node hip_L; its end bone follows
    assert rot.angle(poses, expect).max() < 1e-12


def test_the_weights_choose_the_mode(rig_dir):
    write_dmat(rig_dir / "chain-weights.dmat", np.ones((8, 4)))  # one column per node: node mode
    for f in rig_dir.glob("chain-pose-*.dmat"):
        f.unlink()
    sk, _poses, _ = read_rig(rig_dir / "chain")
    assert sk.n_bones == 4 and sk.names[-1] == "end3"
    write_dmat(rig_dir / "chain-weights.dmat", np.ones((8, 2)))
    with pytest.raises(RigError, match=r"chain\.tgf: the weights have 2 columns; expected one per edge \(3"):
        read_rig(rig_dir / "chain")


@pytest.mark.parametrize(
    ("tgf", "message"),
    [
        ("1 0 0 0\n2 1 0 0\n3 2 0 0\n#\n1 2\n3 2\n", r"node 2 ends two edges"),
        ("1 0 0 0\n2 1 0 0\n3 2 0 0\n4 3 0 0\n#\n1 2\n3 4\n", r"nodes 1, 3 start separate trees"),
        ("1 0 0 0\n2 1 0 0\n#\n1 2\n2 1\n", r"the edges form a cycle"),
        (
            "1 0 0 0\n2 1 0 0\n3 2 0 0\n4 3 0 0\n#\n1 2\n3 4\n4 3\n",
            r"nodes 3, 4 form a cycle apart from the root",
        ),
        ("1 0 0 0\n2 1 0 0\n3 1 0 0\n#\n1 2\n2 3\n", r"edge 2 \(nodes 2 to 3\) has zero length"),
        ("1 0 0 0\n2 1 0 0\n3 5 0 0\n#\n1 2\n", r"node 3 is on no edge"),
        ("1 0 0 0\n#\n", r"the skeleton has no edges"),
        ("1 0 0 0 a\n2 1 0 0 b\n3 2 0 0 b\n#\n1 2\n2 3\n", r"bone names must be unique; repeated: 'b'"),
    ],
)
def test_malformed_skeletons_are_clear_errors(tmp_path, tgf, message):
    (tmp_path / "x.tgf").write_text(tgf)
    m = tgf.split("#")[1].count("\n") - 1
    write_dmat(tmp_path / "x-weights.dmat", np.ones((1, m)))
    with pytest.raises(RigError, match=r"x\.tgf: " + message):
        read_rig(tmp_path / "x")


def test_malformed_poses_weights_and_meshes_are_clear_errors(rig_dir):
    pose = rig_dir / "chain-pose-0001.dmat"
    write_dmat(pose, np.zeros((8, 3)))
    with pytest.raises(
        RigError,
        match=r"chain-pose-0001\.dmat: expected 4 rows per edge and 3 columns, shape \(12, 3\), got \(8, 3\)",
    ):
        read_rig(rig_dir / "chain")
    T = read_dmat(rig_dir / "chain-pose-0000.dmat")
    T[4] *= 2  # edge 2's rotation scaled
    write_dmat(pose, T)
    with pytest.raises(RigError, match=r"chain-pose-0001\.dmat: rows 5 to 7 \(edge 2\) are not a rotation"):
        read_rig(rig_dir / "chain")
    pose.write_text("3 12\n1\n2\n")
    with pytest.raises(RigError, match=r"chain-pose-0001\.dmat: truncated"):
        read_rig(rig_dir / "chain")
    pose.unlink()  # poses stop at the first missing number: 0002 is not read
    assert read_rig(rig_dir / "chain")[1].shape == (1, 3, 4)
    write_dmat(rig_dir / "chain-weights.dmat", np.ones((7, 3)))
    with pytest.raises(
        RigError, match=r"chain-weights\.dmat: 7 rows of weights for the 8 vertices of .*chain\.obj"
    ):
        read_rig(rig_dir / "chain")
    (rig_dir / "chain.obj").write_text("v 0 0 0\nf 1 2 3\n")
    with pytest.raises(RigError, match=r"chain\.obj"):
        read_rig(rig_dir / "chain")
    (rig_dir / "chain-weights.dmat").write_text("3 8\n" + "nan\n" * 24)
    with pytest.raises(RigError, match=r"chain-weights\.dmat: non-finite weights"):
        read_rig(rig_dir / "chain")
    (rig_dir / "chain-weights.dmat").unlink()
    with pytest.raises(RigError, match=r"chain-weights\.dmat: cannot be read"):
        read_rig(rig_dir / "chain")


# ================================================================== ours in theirs and back


@pytest.fixture(scope="module")
def beast():
    return creature(30, n_poses=5, seed=4)


def lbs(rest_points, weights, pose):
    """libigl's ``lbs_matrix`` (M(i, j·4 + c)) applied to a pose file's transforms, written literally."""
    n, m = weights.shape
    M = np.zeros((n, 4 * m))
    for j in range(m):
        for c in range(4):
            M[:, c + j * 4] = weights[:, j] * (rest_points[:, c] if c < 3 else 1.0)
    return M @ pose


def test_our_rig_through_their_files_and_back(tmp_path, beast):
    """Names, rest frames (roll), parents, node weights and poses survive; the creature's bones that do not
    start at their parent's tail hang from pseudo edges."""
    sk, poses = beast
    write_rig(tmp_path / "beast", sk, poses)
    back, poses2, weights = read_rig(tmp_path / "beast")
    assert back.names == sk.names
    np.testing.assert_array_equal(back.parents, sk.parents)
    np.testing.assert_allclose(back.matrix_local, sk.matrix_local, rtol=0, atol=1e-14)
    np.testing.assert_allclose(back.lengths, sk.lengths, rtol=1e-14)
    np.testing.assert_allclose(back.weights, sk.weights, rtol=1e-12)
    assert rot.angle(poses2, poses).max() < 1e-12
    assert weights.shape[1] == sk.n_bones
    tgf = read_tgf(tmp_path / "beast.tgf")
    # Their reducer's assumptions: one root, node 0; edge j ends at node j + 1.
    np.testing.assert_array_equal(tgf.edges[:, 1], np.arange(1, len(tgf.edges) + 1))
    assert tgf.pseudo.sum() > 0 and (tgf.flags[:, 0] == ~tgf.pseudo).all()
    # The pose files move every node as our forward kinematics moves the bones' tails (libigl's LBS of the
    # nodes, each node with its edge's transform).
    edge_of_tail = np.eye(len(tgf.edges))
    for i in range(len(poses)):
        T = read_dmat(tmp_path / f"beast-pose-{i:04d}.dmat")
        moved = lbs(tgf.nodes[1:], edge_of_tail, T)
        bone_tails = moved[~tgf.pseudo]
        np.testing.assert_allclose(bone_tails, sk.forward(poses[i]).tails, atol=1e-12)
    # Their importances (vertex areas times weights) are 3 × our node weights.
    V = np.loadtxt(
        [ln[2:] for ln in (tmp_path / "beast.obj").read_text().splitlines() if ln.startswith("v ")]
    )
    F = (
        np.loadtxt(
            [ln[2:] for ln in (tmp_path / "beast.obj").read_text().splitlines() if ln.startswith("f ")],
            dtype=int,
        )
        - 1
    )
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    vertex_area = np.bincount(F.ravel(), np.repeat(area, 3), len(V))
    W = read_dmat(tmp_path / "beast-weights.dmat")
    np.testing.assert_allclose((vertex_area @ W)[~tgf.pseudo], 3 * sk.weights, rtol=1e-12)


def test_our_rig_with_its_own_mesh_and_skin(tmp_path):
    sk, poses, weights = read_rig(FIXTURES / "chain")
    mesh = (
        np.loadtxt(FIXTURES / "chain.obj", comments=("#", "f"), usecols=(1, 2, 3)),
        np.array([[0, 2, 3], [0, 3, 1], [2, 4, 5], [2, 5, 3], [4, 6, 7], [4, 7, 5]]),
    )
    write_rig(tmp_path / "c", sk, poses, weights, mesh)
    sk2, poses2, weights2 = read_rig(tmp_path / "c")
    np.testing.assert_allclose(sk2.weights, sk.weights, rtol=1e-14)
    np.testing.assert_array_equal(weights2, weights)
    assert rot.angle(poses2, poses).max() < 1e-12
    assert format_tgf(read_tgf(tmp_path / "c.tgf")) == format_tgf(
        TGF(
            read_tgf(FIXTURES / "chain.tgf").nodes,
            np.array([[0, 1], [1, 2], [2, 3]]),
            np.array([[1, 0, 0]] * 3),
            ("", "bone0", "bone1", "bone2"),
        )
    )


def test_rigs_their_files_cannot_hold(tmp_path, beast):
    sk, poses = beast
    two_roots = Skeleton.from_heads_tails(
        ["a", "b"], [-1, -1], [[0, 0, 0], [1, 0, 0]], [[0, 1, 0], [1, 1, 0]]
    )
    with pytest.raises(RigError, match=r"bones 0 'a', 1 'b' are roots with different heads") as err:
        write_rig(tmp_path / "x", two_roots, np.tile(rot.IDENTITY, (1, 2, 1)))
    assert err.value.bones.tolist() == [0, 1]
    for name in ["", " pad", "two\nlines", "x" * 500]:
        named = Skeleton(["a", name], [-1, 0], sk.matrix_local[:2], sk.lengths[:2])
        with pytest.raises(RigError, match=r"bone 1 .*\.tgf"):
            write_rig(tmp_path / "x", named, np.tile(rot.IDENTITY, (1, 2, 1)))
    with pytest.raises(RigError, match=r"skin weights must be finite with shape \(v, 30\)"):
        write_rig(tmp_path / "x", sk, poses, np.ones((4, 3)))
    write_rig(tmp_path / "y", sk, poses)
    with pytest.raises(
        RigError, match=r"y-pose-0002\.dmat: a pose file of an earlier rig would follow the 2 poses"
    ):
        write_rig(tmp_path / "y", sk, poses[:2])


# ================================================================== our reduction in their output files


def test_reduction_golden_output(rig_dir):
    """Joints on the chain's edges 2 and 3: keys are their head nodes 1 and 2 (by hand in the fixtures)."""
    sk, poses, _ = read_rig(rig_dir / "chain")
    r = reduce(sk, poses, Kit(2))
    assert r.joints == (1, 2) and [(p.id, p.parent) for p in r.device] == [(1, 0), (2, 1)]
    setup = write_reduction(rig_dir / "chain", r)
    for what in ("localcos", "restpose", "splitgeo"):
        np.testing.assert_array_equal(
            read_dmat(rig_dir / f"chain-{what}.dmat"),
            read_dmat(FIXTURES / "expected" / f"chain-{what}.dmat"),
            err_msg=what,
        )
    back = read_reduction(rig_dir / "chain")
    np.testing.assert_array_equal(back.localcos, setup.localcos)
    assert back.joints.tolist() == [1, 2]
    for (h, q), pid in zip(back.rest_readings().items(), r.device.joints, strict=True):
        assert rot.angle(q, r.rest[pid]) < 1e-12, h


def test_reduction_of_our_rig_in_their_files(tmp_path, beast):
    """A branching creature with splitters: every joint's frame has its bone along x, restpose maps the
    inlet (slot) frame onto it, the splitter rows give the kind's slots in their axes."""
    sk, poses = beast
    write_rig(tmp_path / "beast", sk, poses)
    sk2, poses2, _ = read_rig(tmp_path / "beast")
    r = reduce(sk2, poses2, Kit(6, {"T": 1, "cross": 1}))
    assert r.device.splitters
    setup = write_reduction(tmp_path / "beast", r)
    tgf = read_tgf(tmp_path / "beast.tgf")
    head_node = tgf.edges[~tgf.pseudo, 0]
    for pid, q in zip(r.device.joints, [r.rest[p] for p in r.device.joints], strict=True):
        b = r.bones[pid]
        F = setup.localcos[head_node[b]]
        np.testing.assert_allclose(F[:, 0], sk2.matrix_local[b, :3, 1], atol=1e-15)  # their x: our bone
        inlet = sk2.matrix_local[b, :3, :3] @ rot.to_matrix(q).T  # the frame the joint is plugged into
        np.testing.assert_allclose(
            setup.restpose[head_node[b]] @ inlet, sk2.matrix_local[b, :3, :3], atol=1e-12
        )
    rows = setup.splitgeo
    n_slots = sum(r.device[s].valence for s in r.device.splitters)
    chained = [
        p for p in r.device.joints if r.device[p].parent == 0 or r.device[r.device[p].parent].kind == "joint"
    ]
    assert len(rows) == n_slots + len(chained)
    first = r.device[r.device.splitters[0]]
    for j, (roll, pitch, yaw) in enumerate(rows[: first.valence, 2:]):
        c, s = np.cos, np.sin
        Rz = np.array([[c(yaw), -s(yaw), 0], [s(yaw), c(yaw), 0], [0, 0, 1]])
        Ry = np.array([[c(pitch), 0, s(pitch)], [0, 1, 0], [-s(pitch), 0, c(pitch)]])
        Rx = np.array([[1, 0, 0], [0, c(roll), -s(roll)], [0, s(roll), c(roll)]])
        np.testing.assert_allclose(
            THEIR_AXES @ Rz @ Ry @ Rx @ THEIR_AXES.T, rot.to_matrix(first.splitter.slots[j]), atol=1e-15
        )
    assert np.all(rows[n_slots:, 2:] == 0)
    read_back = read_reduction(tmp_path / "beast")
    np.testing.assert_array_equal(read_back.splitgeo, rows)
    np.testing.assert_array_equal(read_back.restpose, setup.restpose)


def test_joints_on_sibling_bones_share_a_key_and_the_later_edge_wins(tmp_path):
    """A Y of connected bones: the two branch joints leave the same node (their ExportSetup's rule)."""
    sk = Skeleton.from_heads_tails(
        ["root", "stem", "right", "left"],
        [-1, 0, 1, 1],
        [[0, 0, 0], [0, 1, 0], [0, 2, 0], [0, 2, 0]],
        [[0, 1, 0], [0, 2, 0], [1, 2, 0], [-1, 2, 0]],
    )
    rng = np.random.default_rng(0)
    poses = rot.from_rotvec(rng.normal(scale=0.3, size=(6, 4, 3)))
    r = reduce(sk, poses, Kit(3, {"T": 1}))
    assert sorted(r.joints) == [1, 2, 3] and r.device.splitters
    write_rig(tmp_path / "y", sk, poses)
    setup = write_reduction(tmp_path / "y", r)
    assert setup.joints.tolist() == [1, 2]  # stem's head (node 1) and the fork (node 2)
    left = next(p for p in r.device.joints if r.bones[p] == 3)
    np.testing.assert_allclose(setup.localcos[2] @ THEIR_AXES.T, sk.matrix_local[3, :3, :3], atol=1e-15)
    assert rot.angle(setup.rest_readings()[2], r.rest[left]) < 1e-12
    slot_rows = setup.splitgeo[:2]
    assert sorted(slot_rows[:, 1].tolist()) == [2, 2] and slot_rows[0, 0] == 1


def test_reduction_errors(tmp_path, rig_dir):
    sk, poses, _ = read_rig(rig_dir / "chain")
    r = reduce(sk, poses, Kit(2))
    other, _ = creature(20, n_poses=2)
    with pytest.raises(RigError, match="not the one the reduction was computed for"):
        write_reduction(rig_dir / "chain", r, other)
    (rig_dir / "fork.tgf").rename(rig_dir / "chain.tgf")
    (rig_dir / "fork-weights.dmat").rename(rig_dir / "chain-weights.dmat")
    with pytest.raises(RigError, match=r"chain\.tgf: bones 0 'bone0', 1 'bone1', 2 'bone2' match no edge"):
        write_reduction(rig_dir / "chain", r)
    # Without a .tgf, the rig is numbered as write_rig numbers it, and written.
    setup = write_reduction(tmp_path / "fresh", r)
    assert read_tgf(tmp_path / "fresh.tgf").edges.tolist() == [[0, 1], [1, 2], [2, 3]]
    assert setup.joints.tolist() == [1, 2]
    (tmp_path / "fresh-splitgeo.dmat").write_text("4 1\n1\n2\n3\n4\n")
    with pytest.raises(RigError, match=r"fresh-splitgeo\.dmat: expected 5 columns, got \(1, 4\)"):
        read_reduction(tmp_path / "fresh")
    write_dmat(tmp_path / "fresh-restpose.dmat", np.zeros((9, 3)))
    with pytest.raises(RigError, match=r"disagree on the node count: 4 and 3"):
        read_reduction(tmp_path / "fresh")
    write_dmat(tmp_path / "fresh-localcos.dmat", np.zeros((8, 3)))
    with pytest.raises(RigError, match=r"fresh-localcos\.dmat: expected 3 columns and 3 rows per node"):
        read_reduction(tmp_path / "fresh")


@given(st.data())
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_read_rig_on_damaged_fixture_files_raises_only_rig_errors(tmp_path, data):
    name = data.draw(st.sampled_from(["chain.tgf", "chain-weights.dmat", "chain-pose-0001.dmat", "fork.tgf"]))
    raw = bytearray((FIXTURES / name).read_bytes())
    for _ in range(data.draw(st.integers(1, 3))):
        i = data.draw(st.integers(0, len(raw) - 1))
        raw[i] = data.draw(st.sampled_from(b"0123456789 .-#\nxe"))
    work = tmp_path / f"case{next(CASES)}"
    work.mkdir()
    for f in FIXTURES.glob("*.*"):
        shutil.copy(f, work / f.name)
    (work / name).write_bytes(bytes(raw))
    with contextlib.suppress(RigError):
        read_rig(work / name.split("-")[0].split(".")[0])
