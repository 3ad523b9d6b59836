"""The versioned ``.npz`` motion format (solver.retarget.motion): round trips, atomic writes, frame
selection, CSR contacts, and refusal of every malformed or corrupted file with a MotionError that names
the member at fault."""

import io
import os
import re
import zipfile
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from geodesics import SurfacePoints
from geodesics.primitives import icosphere
from solver.objects import box
from solver.retarget.motion import FORMAT, VERSION, Contacts, Motion, MotionError
from solver.rotations import axis_angle_to_matrix

F = 5
REQUIRED = (
    "format",
    "version",
    "fps",
    "object_mesh_vertices",
    "object_mesh_faces",
    "object_poses",
    "hand_mesh_vertices",
    "hand_mesh_faces",
    "hand_vertices",
    "source_scale",
)


def _random_points(rng, n_faces: int, k: int) -> SurfacePoints:
    bary = rng.dirichlet([1.0, 1.0, 1.0], k)
    if k:
        bary[0] = [0.0, 1.0, 0.0]  # a corner: exact zeros must survive
    return SurfacePoints(rng.integers(0, n_faces, k), bary)


def _rigid(rng, n: int) -> np.ndarray:
    aa = np.concatenate([rng.uniform(0, np.pi, (n, 1)), rng.normal(size=(n, 3))], 1)
    aa[:, 1:] /= np.linalg.norm(aa[:, 1:], axis=1, keepdims=True)
    T = np.zeros((n, 4, 4))
    T[:, :3, :3] = axis_angle_to_matrix(aa)
    T[:, :3, 3] = rng.normal(scale=0.1, size=(n, 3))
    T[:, 3, 3] = 1.0
    return T


def make_motion(full: bool = True, frames: int = F, seed: int = 0) -> Motion:
    """A small motion: a box object, an icosphere 'hand'; ``full`` adds every optional member."""
    rng = np.random.default_rng(seed)
    obj = box(cells=2)
    hand = icosphere(1, radius=0.02)
    V = hand.vertices[None] + rng.normal(scale=0.01, size=(frames, hand.n_vertices, 3))
    kwargs = {}
    if full:
        counts = rng.integers(0, 7, frames)
        counts[0], counts[1], counts[-1] = 3, 0, 0  # frames without contacts, one with
        obj_points = [_random_points(rng, obj.n_faces, c) for c in counts]
        hand_points = [_random_points(rng, hand.n_faces, c) for c in counts]
        table = np.eye(4)
        table[:3, 3] = [0.1, 0.0, -0.02]
        kwargs = dict(
            object_contacts=Contacts.from_frames(obj_points),
            hand_contacts=Contacts.from_frames(hand_points),
            table=table,
            table_size=[1.0, 0.8, 0.04],
            source_kind="human",
            source_scale=0.8,
            source_theta=rng.normal(size=(frames, 12)),
            first_frame=0,  # as a GRAB import numbers its frames
        )
    return Motion(
        fps=120.0,
        object_mesh=obj,
        object_poses=_rigid(rng, frames),
        hand_mesh=hand,
        hand_vertices=V,
        **kwargs,
    )


@pytest.fixture(scope="module")
def full() -> Motion:
    return make_motion(True)


@pytest.fixture(scope="module")
def bare() -> Motion:
    return make_motion(False)


@pytest.fixture(scope="module")
def saved(full, tmp_path_factory) -> bytes:
    """The bytes of a saved full motion (uncompressed)."""
    path = tmp_path_factory.mktemp("motion") / "m.npz"
    full.save(path)
    return path.read_bytes()


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def _assert_identical(a: Motion, b: Motion) -> None:
    A, B = a.to_arrays(), b.to_arrays()
    assert sorted(A) == sorted(B)
    for name in A:
        assert _same_bits(np.asarray(A[name]), np.asarray(B[name])), name


def _write(path, arrays: dict) -> None:
    np.savez(path, **arrays)


def _load_error(tmp_path, arrays: dict) -> MotionError:
    path = tmp_path / "bad.npz"
    _write(path, arrays)
    with pytest.raises(MotionError) as info:
        Motion.load(path)
    return info.value


# ------------------------------------------------------------------ round trips


@pytest.mark.parametrize("which", ["full", "bare"])
@pytest.mark.parametrize("compressed", [False, True])
def test_save_load_round_trip_is_bit_exact(which, compressed, request, tmp_path):
    motion = request.getfixturevalue(which)
    path = tmp_path / "motion.npz"
    motion.save(path, compressed=compressed)
    loaded = Motion.load(path)
    _assert_identical(motion, loaded)
    assert loaded.fps == motion.fps and loaded.source_scale == motion.source_scale
    assert loaded.source_kind == motion.source_kind
    if which == "bare":
        for name in (
            "object_contacts",
            "hand_contacts",
            "table",
            "table_size",
            "source_kind",
            "source_theta",
        ):
            assert getattr(loaded, name) is None, name
        assert loaded.source_scale == 1.0
    else:
        for f in range(F):
            a, b = motion.object_contacts.frame(f), loaded.object_contacts.frame(f)
            assert np.array_equal(a.faces, b.faces) and np.array_equal(a.bary, b.bary)
    with zipfile.ZipFile(path) as z:
        members = sorted(n[:-4] for n in z.namelist())
        assert {i.compress_type for i in z.infolist()} == {zipfile.ZIP_DEFLATED if compressed else 0}
    assert members == sorted(motion.to_arrays())
    assert set(REQUIRED) <= set(members)


def test_file_members_are_documented_types(saved, tmp_path):
    path = tmp_path / "m.npz"
    path.write_bytes(saved)
    with np.load(path, allow_pickle=False) as z:
        assert str(z["format"]) == FORMAT and z["format"].dtype.kind == "U"
        assert int(z["version"]) == VERSION == 1 and z["version"].dtype == np.int64
        assert z["object_poses"].shape == (F, 4, 4) and z["object_poses"].dtype == np.float64
        assert z["object_contacts_offsets"].shape == (F + 1,) and z["object_contacts_offsets"][0] == 0
        assert z["hand_contacts_bary"].dtype == np.float64


def test_narrower_dtypes_are_widened(full, tmp_path):
    arrays = dict(full.to_arrays())
    arrays["hand_mesh_faces"] = arrays["hand_mesh_faces"].astype(np.int32)
    arrays["object_contacts_faces"] = arrays["object_contacts_faces"].astype(np.uint16)
    arrays["hand_vertices"] = arrays["hand_vertices"].astype(np.float32)
    path = tmp_path / "narrow.npz"
    _write(path, arrays)
    m = Motion.load(path)
    assert m.hand_mesh.faces.dtype == np.int64 and m.object_contacts.faces.dtype == np.int64
    assert m.hand_vertices.dtype == np.float64
    assert np.array_equal(m.hand_vertices, full.hand_vertices.astype(np.float32).astype(np.float64))


def test_arrays_are_read_only_copies(full):
    V = np.array(full.hand_vertices)
    m = Motion(fps=30, object_mesh=full.object_mesh, object_poses=full.object_poses,
               hand_mesh=full.hand_mesh, hand_vertices=V)  # fmt: skip
    V[:] = 0.0
    assert not np.array_equal(m.hand_vertices, V)
    with pytest.raises(ValueError):
        m.hand_vertices[0, 0, 0] = 1.0
    assert m.duration == pytest.approx((F - 1) / 30)


# ------------------------------------------------------------------ atomic write


class _Boom(Exception):
    pass


class _Exploding:
    """Turns into an array only to fail, after np.savez has written the other members."""

    def __init__(self, error):
        self.error = error

    def __array__(self, *args, **kwargs):
        raise self.error("disk on fire")


@pytest.mark.parametrize("error", [_Boom, KeyboardInterrupt])
def test_failing_save_leaves_existing_file_intact(full, bare, tmp_path, monkeypatch, error):
    path = tmp_path / "motion.npz"
    bare.save(path)
    before = path.read_bytes()
    original = Motion.to_arrays
    monkeypatch.setattr(Motion, "to_arrays", lambda self: {**original(self), "zzz": _Exploding(error)})
    with pytest.raises(error):
        full.save(path)
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["motion.npz"]  # no temporary left behind
    _assert_identical(Motion.load(path), bare)
    full.save(path)  # and a later save replaces it
    _assert_identical(Motion.load(path), full)


def test_save_honours_umask(bare, tmp_path):
    old = os.umask(0o022)
    try:
        bare.save(tmp_path / "m.npz")
    finally:
        os.umask(old)
    assert (tmp_path / "m.npz").stat().st_mode & 0o777 == 0o644


# ------------------------------------------------------------------ contacts and selection


def test_contacts_from_frames_round_trip():
    rng = np.random.default_rng(4)
    counts = [3, 0, 0, 5, 1, 0]
    frames = [_random_points(rng, 40, c) for c in counts]
    c = Contacts.from_frames(frames)
    assert c.n_frames == 6 and len(c) == 9
    assert c.count().tolist() == counts
    assert c.offsets.tolist() == [0, 3, 3, 3, 8, 9, 9]
    assert c.frame_index().tolist() == [0, 0, 0, 3, 3, 3, 3, 3, 4]
    for f, p in enumerate(frames):
        q = c.frame(f)
        assert _same_bits(q.faces, p.faces) and _same_bits(q.bary, p.bary)
    assert np.array_equal(c.frame(-3).faces, frames[3].faces)
    back = Contacts.from_frames([c.frame(f) for f in range(c.n_frames)])
    assert _same_bits(back.offsets, c.offsets) and _same_bits(back.bary, c.bary)
    with pytest.raises(MotionError, match="out of range") as info:
        c.frame(6)
    assert info.value.field == "frame"
    empty = Contacts.from_frames([])
    assert empty.n_frames == 0 and len(empty) == 0


def test_contacts_select():
    rng = np.random.default_rng(5)
    frames = [_random_points(rng, 40, k) for k in (2, 0, 4, 1)]
    c = Contacts.from_frames(frames)
    s = c.select([3, 0, 0, -2])
    assert s.count().tolist() == [1, 2, 2, 4]
    for got, want in zip(range(4), [3, 0, 0, 2], strict=True):
        assert np.array_equal(s.frame(got).faces, frames[want].faces)
        assert np.array_equal(s.frame(got).bary, frames[want].bary)
    assert c.select(slice(None, None, 2)).count().tolist() == [2, 4]
    assert c.select(np.array([False, True, True, False])).count().tolist() == [0, 4]
    assert c.select([]).n_frames == 0


@pytest.mark.parametrize(
    "offsets, faces, bary, field",
    [
        ([1, 2], [0, 0], np.full((2, 3), 1 / 3), "offsets"),
        ([0, 2, 1], [0], np.full((1, 3), 1 / 3), "offsets"),
        ([0, 3], [0, 0], np.full((2, 3), 1 / 3), "offsets"),
        ([0, 1], [-1], np.full((1, 3), 1 / 3), "faces"),
        ([0, 1], [0.5], np.full((1, 3), 1 / 3), "faces"),
        ([0, 1], [0], [[0.5, 0.6, -0.1]], "bary"),
        ([0, 1], [0], [[np.nan, 0.5, 0.5]], "bary"),
        ([0, 1], [0], [[0.5, 0.5]], "bary"),
    ],
)
def test_contacts_refuse_malformed(offsets, faces, bary, field):
    with pytest.raises(MotionError) as info:
        Contacts(offsets, faces, bary)
    assert info.value.field == field


def test_motion_select(full):
    ids = [4, 0, 2, 2, -1]
    s = full.select(ids)
    want = [4, 0, 2, 2, 4]
    assert s.n_frames == 5
    assert np.array_equal(s.object_poses, full.object_poses[want])
    assert np.array_equal(s.hand_vertices, full.hand_vertices[want])
    assert np.array_equal(s.source_theta, full.source_theta[want])
    for g, w in enumerate(want):
        for name in ("object_contacts", "hand_contacts"):
            a, b = getattr(s, name).frame(g), getattr(full, name).frame(w)
            assert np.array_equal(a.faces, b.faces) and np.array_equal(a.bary, b.bary)
    assert s.object_mesh is full.object_mesh and np.array_equal(s.table, full.table)
    assert full.select(slice(1, None, 2)).object_poses.tobytes() == full.object_poses[1::2].tobytes()
    mask = np.array([True, False, False, True, False])
    assert np.array_equal(full.select(mask).hand_vertices, full.hand_vertices[mask])
    for bad in ([], [5], [-6], [0.5], np.ones(3, bool)):
        with pytest.raises(MotionError) as info:
            full.select(bad)
        assert info.value.field == "frame"


def test_first_frame_is_kept_by_the_file_and_by_a_window(full, bare, tmp_path):
    """The scene's number of frame 0 survives a save and load, is left out of the file at its default
    (1), and a window of consecutive frames keeps the scene's numbering."""
    assert full.first_frame == 0 and bare.first_frame == 1 and "first_frame" not in bare.to_arrays()
    full.save(tmp_path / "m.npz")
    assert Motion.load(tmp_path / "m.npz").first_frame == 0
    bare.save(tmp_path / "b.npz")
    assert Motion.load(tmp_path / "b.npz").first_frame == 1
    assert full.select(slice(2, 4)).first_frame == 2
    assert replace(bare, first_frame=10).select([3, 4]).first_frame == 13
    for bad in (1.5, "1", True):
        with pytest.raises(MotionError, match="first_frame must be a whole number") as info:
            replace(bare, first_frame=bad)
        assert info.value.field == "first_frame"


# ------------------------------------------------------------------ construction errors


def test_motion_refuses_invalid_construction(full):
    base = dict(fps=120.0, object_mesh=full.object_mesh, object_poses=full.object_poses,
                hand_mesh=full.hand_mesh, hand_vertices=full.hand_vertices)  # fmt: skip
    cases = [
        ({"fps": 0.0}, "fps"),
        ({"fps": "fast"}, "fps"),
        ({"object_poses": np.zeros((0, 4, 4))}, "object_poses"),
        ({"hand_vertices": full.hand_vertices[:-1]}, "hand_vertices"),
        ({"object_contacts": full.object_contacts,
          "hand_contacts": full.hand_contacts.select([1, 0, 2, 3, 4])},
         "hand_contacts.offsets"),
        ({"object_contacts": full.hand_contacts}, "object_contacts.faces"),  # hand faces on the object
        ({"object_contacts": full.object_contacts.select([0, 1])}, "object_contacts.offsets"),
        ({"table": np.eye(4)}, "table_size"),
        ({"table": np.eye(4), "table_size": [1, 0, 1]}, "table_size"),
        ({"source_theta": np.zeros((F - 1, 3))}, "source_theta"),
        ({"source_scale": -1.0}, "source_scale"),
        ({"source_kind": 3}, "source_kind"),
    ]  # fmt: skip
    for change, field in cases:
        with pytest.raises(MotionError) as info:
            Motion(**{**base, **change})
        assert info.value.field == field, (change, str(info.value))


# ------------------------------------------------------------------ file errors


def _poses_with(full, f, change):
    P = np.array(full.object_poses)
    change(P[f])
    return P


@pytest.mark.parametrize(
    "member, value, field, message",
    [
        ("version", np.array(2), "version", "newer"),
        ("version", np.array(0), "version", "not supported"),
        ("format", np.array("something/else"), "format", "not a motion file"),
        ("format", np.array(b"contact-edit/motion"), "format", "unicode"),
        ("fps", np.array(np.nan), "fps", "finite"),
        ("fps", np.array(120), "fps", "floating"),
        ("fps", np.array([120.0]), "fps", "shape"),
        ("object_poses", np.zeros((F, 3, 4)), "object_poses", "shape"),
        ("object_poses", "nan", "object_poses", "NaN"),
        ("object_poses", "scaled", "object_poses", "rigid"),
        ("object_poses", "mirrored", "object_poses", "rigid"),
        ("object_poses", "projective", "object_poses", "rigid"),
        ("hand_vertices", "short", "hand_vertices", "shape"),
        ("hand_vertices", "inf", "hand_vertices", "NaN"),
        ("hand_mesh_vertices", "nan", "hand_mesh_vertices", "NaN"),
        ("object_mesh_faces", "out of range", "object_mesh_faces", "object_mesh"),
        ("object_mesh_faces", np.zeros((4, 3), np.float64), "object_mesh_faces", "integer"),
        ("object_contacts_faces", "out of range", "object_contacts_faces", "outside"),
        ("hand_contacts_faces", "negative", "hand_contacts_faces", "non-negative"),
        ("object_contacts_offsets", "decreasing", "object_contacts_offsets", "non-decreasing"),
        ("object_contacts_offsets", "short", "object_contacts_offsets", "frames"),
        ("hand_contacts_offsets", "unpaired", "hand_contacts_offsets", "paired"),
        ("object_contacts_bary", "negative", "object_contacts_bary", "barycentric"),
        ("table", "scaled", "table", "rigid"),
        ("table_size", np.array([1.0, -1.0, 1.0]), "table_size", "positive"),
        ("source_theta", np.zeros((F + 1, 3)), "source_theta", "shape"),
        ("source_kind", np.array(7), "source_kind", "unicode"),
        ("table_size", None, "table_size", "together"),
        ("hand_contacts_bary", None, "hand_contacts_bary", "incomplete"),
        ("object_poses", None, "object_poses", "missing"),
        ("surprise", np.zeros(3), "surprise", "unexpected"),
    ],
)
def test_load_refuses_invalid_members(full, tmp_path, member, value, field, message):
    arrays = {k: np.array(v) for k, v in full.to_arrays().items()}
    if value is None:
        del arrays[member]
    elif isinstance(value, str):
        a = arrays[member]
        if value == "nan":
            a[(1,) * (a.ndim - 1) + (2,)] = np.nan
        elif value == "inf":
            a[2, 3, 0] = -np.inf
        elif value == "scaled":
            a[(..., slice(0, 3), slice(0, 3))] *= 1.001
        elif value == "mirrored":
            a[3, :3, 0] *= -1
        elif value == "projective":
            a[0, 3, 0] = 0.01
        elif value == "short":
            a = a[:-1]
        elif value == "out of range":
            n = (
                full.object_mesh.n_faces
                if member.startswith("object_contacts")
                else full.object_mesh.n_vertices
            )
            a[-1] = n
        elif value == "negative":
            a[0] = -1 if a.ndim == 1 else [-0.25, 0.75, 0.5]
        elif value == "decreasing":
            a[2], a[3] = a[3], a[2] - 1
        elif value == "unpaired":  # frames 0 and 1 swapped: 3 and 0 contacts against 0 and 3
            swapped = full.hand_contacts.select([1, 0, 2, 3, 4])
            a = swapped.offsets
            arrays["hand_contacts_faces"], arrays["hand_contacts_bary"] = swapped.faces, swapped.bary
        arrays[member] = a
    else:
        arrays[member] = value
    err = _load_error(tmp_path, arrays)
    assert err.field == field, str(err)
    assert message in str(err), str(err)
    assert "bad.npz" in str(err)


def test_load_never_unpickles(full, tmp_path):
    arrays = dict(full.to_arrays())
    arrays["source_kind"] = np.array({"evil": "payload"}, dtype=object)
    path = tmp_path / "pickle.npz"
    np.savez(path, **arrays)  # stores source_kind as a pickle
    with pytest.raises(MotionError, match="pickle") as info:
        Motion.load(path)
    assert info.value.field == "source_kind"


def _garbage_files(saved: bytes) -> dict[str, bytes]:
    empty_zip = io.BytesIO()
    zipfile.ZipFile(empty_zip, "w").close()
    other = io.BytesIO()
    with zipfile.ZipFile(other, "w") as z:
        z.writestr("readme.txt", "hello")
    return {
        "empty": b"",
        "text": b"frame,x,y,z\n0,1,2,3\n",
        "random": np.random.default_rng(0).bytes(4096),
        "npy": saved[:0] + b"\x93NUMPY\x01\x00" + b" " * 100,
        "empty zip": empty_zip.getvalue(),
        "non-npy member": other.getvalue(),
        **{
            f"truncated to {n}": saved[:n]
            for n in (10, 100, len(saved) // 2, len(saved) - 23, len(saved) - 1)
        },
    }


def test_load_refuses_garbage_and_truncated_files(saved, tmp_path):
    for name, data in _garbage_files(saved).items():
        path = tmp_path / "garbage.npz"
        path.write_bytes(data)
        with pytest.raises(MotionError) as info:
            Motion.load(path)
        assert info.value.field, name
        assert "garbage.npz" in str(info.value), name
    with pytest.raises(MotionError, match="no such file"):
        Motion.load(tmp_path / "missing.npz")
    with pytest.raises(MotionError, match="directory"):
        Motion.load(tmp_path)


def test_load_refuses_a_header_that_lies_about_the_size(full, tmp_path):
    """A member whose .npy header promises far more data than is stored: refused before any allocation."""
    path = tmp_path / "lie.npz"
    with zipfile.ZipFile(path, "w") as z:
        for name, a in full.to_arrays().items():
            a = np.asarray(a)
            buf = io.BytesIO()
            if name == "hand_vertices":
                header = {"descr": "<f8", "fortran_order": False, "shape": (10**9, *a.shape[1:])}
                np.lib.format.write_array_header_1_0(buf, header)
                buf.write(a.tobytes())
            else:
                np.lib.format.write_array(buf, a, allow_pickle=False)
            z.writestr(name + ".npy", buf.getvalue())
    with pytest.raises(MotionError, match="promises") as info:
        Motion.load(path)
    assert info.value.field == "hand_vertices"


# ------------------------------------------------------------------ fuzz


@settings(max_examples=150, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_fuzz_corrupted_bytes_give_motion_error_or_a_clean_load(saved, tmp_path_factory, data):
    """Flip, overwrite, insert or cut bytes anywhere in a saved file (headers, zip directory, data):
    the only outcomes are a MotionError or a valid motion."""
    blob = bytearray(saved)
    starts = [m.start() for m in re.finditer(b"PK\x03\x04", saved)]  # zip local headers; .npy headers follow
    assert len(starts) == 21  # one per member of a full motion
    n_edits = data.draw(st.integers(1, 4))
    for _ in range(n_edits):
        kind = data.draw(st.sampled_from(["flip", "set", "insert", "delete", "truncate"]))
        # Aim half the edits at the zip directory and .npy headers (the end and starts of members).
        pos = data.draw(
            st.one_of(
                st.integers(0, len(blob) - 1),
                st.integers(max(0, len(blob) - 600), len(blob) - 1),
                st.sampled_from([i + d for i in starts for d in range(0, 140, 3) if i + d < len(blob)]),
            )
        )
        pos = min(pos, len(blob) - 1)
        if kind == "flip":
            blob[pos] ^= 1 << data.draw(st.integers(0, 7))
        elif kind == "set":
            blob[pos] = data.draw(st.integers(0, 255))
        elif kind == "insert":
            blob[pos:pos] = data.draw(st.binary(min_size=1, max_size=8))
        elif kind == "delete":
            del blob[pos : pos + data.draw(st.integers(1, 16))]
        else:
            del blob[pos:]
        if not blob:
            blob = bytearray(b"\x00")
    path = tmp_path_factory.mktemp("fuzz") / "fuzzed.npz"
    path.write_bytes(bytes(blob))
    try:
        motion = Motion.load(path)
    except MotionError as err:
        assert err.field
        return
    assert isinstance(motion, Motion) and motion.n_frames >= 1


_KINDS = {"f": "f", "i": "iu", "U": "U"}
_DOCUMENTED = {  # member: (dtype kind, ndim), as the module docstring's tables give them
    "format": ("U", 0), "version": ("i", 0), "fps": ("f", 0), "object_mesh_vertices": ("f", 2),
    "object_mesh_faces": ("i", 2), "object_poses": ("f", 3), "hand_mesh_vertices": ("f", 2),
    "hand_mesh_faces": ("i", 2), "hand_vertices": ("f", 3), "source_scale": ("f", 0),
    "object_contacts_offsets": ("i", 1), "object_contacts_faces": ("i", 1), "object_contacts_bary": ("f", 2),
    "hand_contacts_offsets": ("i", 1), "hand_contacts_faces": ("i", 1), "hand_contacts_bary": ("f", 2),
    "table": ("f", 2), "table_size": ("f", 1), "source_kind": ("U", 0), "source_theta": ("f", 2),
    "first_frame": ("i", 0),
}  # fmt: skip


def test_documented_members_are_those_written(full):
    assert {
        k: (np.asarray(v).dtype.kind.replace("u", "i"), np.ndim(v)) for k, v in full.to_arrays().items()
    } == (_DOCUMENTED)


@settings(max_examples=120, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(
    member=st.sampled_from(sorted(_DOCUMENTED)),
    dtype=st.sampled_from(["f8", "f4", "i8", "i2", "u1", "b1", "c16", "U3", "S3", "M8[s]"]),
    shape=st.lists(st.integers(0, 6), max_size=4).map(tuple),
    fill=st.sampled_from(["zeros", "random", "nan", "huge"]),
    seed=st.integers(0, 2**16),
)
def test_fuzz_replaced_members_give_motion_error_or_a_clean_load(full, tmp_path_factory, member, dtype, shape,
                                                                 fill, seed):  # fmt: skip
    """Any member replaced by an array of any dtype, shape and content: a MotionError that names that
    member when its dtype or rank is wrong, and some member otherwise (a replacement can break another
    member, e.g. faces that the contacts refer to), or a clean load when it happens to be valid."""
    rng = np.random.default_rng(seed)
    if fill == "zeros" or dtype == "M8[s]":
        value = np.zeros(shape, dtype)
    elif dtype.startswith(("U", "S")):
        value = np.full(shape, "abc", dtype)
    else:
        raw = {
            "random": rng.normal(size=shape) * 5,
            "nan": np.full(shape, np.nan),
            "huge": np.full(shape, 1e30),
        }
        with np.errstate(invalid="ignore", over="ignore"):
            value = raw[fill].astype(dtype)
    path = tmp_path_factory.mktemp("members") / "m.npz"
    np.savez(path, **{**full.to_arrays(), member: value})
    try:
        Motion.load(path)
    except MotionError as err:
        kind, ndim = _DOCUMENTED[member]
        if value.dtype.kind not in _KINDS[kind] or value.ndim != ndim:
            assert err.field == member, (str(err), err.field)
        else:
            assert err.field in _DOCUMENTED, (str(err), err.field)
