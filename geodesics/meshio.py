"""Mesh files in and out (OBJ, PLY, OFF, STL, glTF/GLB), keeping the file's vertex and face numbering.

=========  =====================================================  =====================================
format     read                                                   written as
=========  =====================================================  =====================================
OBJ        ``v`` and ``f`` records (uv, normals, groups ignored)  text, 17 significant digits: float64
PLY        ASCII and binary (either byte order)                   binary little endian, float64
OFF        OFF and its C/N/ST variants                            text, 17 significant digits: float64
STL        binary and ASCII, through trimesh                      binary, through trimesh: float32
glTF/GLB   one mesh, through trimesh                              trimesh, embedded buffers: float32
=========  =====================================================  =====================================

**Index guarantee.** Contact files name faces and vertices by index, so a loaded mesh keeps the file's
numbering. Vertex i is the file's i-th vertex; vertices no face uses are kept (see
:class:`~geodesics.TriMesh`). OBJ, PLY and OFF hold polygons: they are triangulated by
:meth:`TriMesh.from_polygons <geodesics.TriMesh.from_polygons>` polygon by polygon in file order, so the
triangles of polygon p come before those of polygon p + 1 (``mesh.triangle_polygon`` maps each triangle
back), a triangle is kept as it is, a quad is split as Blender splits it and a larger polygon is
ear-clipped: the add-on's triangulation of a Blender mesh, so a file with a Blender mesh's vertices and
polygons in Blender's order gets the add-on's face numbering. An OBJ file with several objects, groups or
materials is read whole, faces in file order: OBJ numbers its vertices across the whole file, so the
indices stay well defined. A glTF file must hold one mesh (one primitive, placed once; its node transform
is applied): separate glTF meshes and primitives each number their vertices from zero and exporters do not
keep their order, so joining them would not give well-defined indices, and such a file is refused with the
names of its geometries. STL stores each triangle with its own three corners and no indices: it must be
loaded with ``merge=True``, which joins corners with equal coordinates; vertices are then numbered in
order of first use and faces keep the file's order.

**trimesh, and where ours is kept.** trimesh (checked with 5.2) reads and writes STL and glTF/GLB. OBJ,
PLY and OFF are read and written here, because trimesh renumbers them, whatever its options: its OBJ
reader makes a separate mesh of each ``usemtl`` section (the last section first), drops vertices after the
last one a face uses and, unless ``maintain_order``, duplicates vertices that carry several uv
coordinates or normals; its polygon triangulation reorders faces (OFF, PLY and all-quad OBJ files get the
file's triangles first, then the first halves of all quads, then their second halves) and splits quads
otherwise than Blender; it cannot read binary PLY whose polygons differ in size (Blender's PLY export);
and its writers round coordinates (OBJ to 8 decimals, OFF to 10, PLY to float32). trimesh is imported only to
read or write STL and glTF: it is slow to import, and the Blender extension does not ship it.

trimesh's geometric queries are the independent oracle of ``tests/test_trimesh_oracle.py`` rather than
replacements for ours. :class:`solver.sdf.MeshSDF` and :meth:`SurfacePoints.nearest
<geodesics.SurfacePoints.nearest>` examine every face that could hold a closer point with scale-free
tests, and MeshSDF takes the sign from the angle-weighted pseudonormal of the closest feature, exact on
closed meshes; trimesh's closest points use absolute tolerances (1e-13 on dot products, 1e-8 on squared
distances), so on a mug in metres, a tenth of a millimetre away, they can be a neighbouring face's point
several percent farther, and its signed distance signs points near edges and vertices by ray-cast
containment. :class:`solver.retarget.pairing.RayCaster` casts whole lines (the pairing needs hits behind
a contact), all rays at once through a numpy BVH in float64, reporting a crossing through an edge once as
the hit parity needs; trimesh's pure-Python caster casts half-lines with an r-tree query per ray.
:func:`solver.retarget.metrics.ray_winding` counts exact winding numbers (symbolic perturbation), which
trimesh does not offer.
"""

from __future__ import annotations

import json
import re
import struct
from pathlib import Path

import numpy as np

from .errors import MeshError, describe_ids
from .files import write_atomically
from .mesh import TriMesh

#: File types by extension (``file_type`` takes the same names).
FILE_TYPES = {".obj": "obj", ".ply": "ply", ".off": "off", ".stl": "stl", ".gltf": "gltf", ".glb": "glb"}

_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
_STRUCT_CODES = {"i1": "b", "u1": "B", "i2": "h", "u2": "H", "i4": "i", "u4": "I", "f4": "f", "f8": "d"}
_PLY_INDEX_NAMES = ("vertex_indices", "vertex_index")
_OFF_HEADER = re.compile(r"(ST)?C?N?OFF")


# ------------------------------------------------------------------------------------------------ public


def load_mesh(path, file_type: str | None = None, *, merge: bool = False) -> TriMesh:
    """Read a triangle or polygon mesh from an OBJ, PLY, OFF, STL, glTF or GLB file.

    Parameters
    ----------
    path : str or os.PathLike
    file_type : str, optional
        ``"obj"``, ``"ply"``, ``"off"``, ``"stl"``, ``"gltf"`` or ``"glb"``; by default from the extension.
    merge : bool
        Join vertices with exactly equal coordinates (numbered in order of first occurrence in the file's
        vertex list; faces keep their order). Needed for STL, which stores a triangle soup.

    Returns
    -------
    TriMesh
        With the file's vertex numbering and its faces in file order (see the module docstring); built by
        :meth:`TriMesh.from_polygons` when the file has polygons of more than three corners.

    Raises
    ------
    MeshError
        For a missing, unreadable, truncated or malformed file, an unknown extension, a file with no faces
        (empty, or a point cloud), a glTF file with several meshes, an STL file without ``merge``, or a
        mesh that :class:`TriMesh` rejects (NaN coordinates, out-of-range indices, non-manifold, ...).
        The message starts with the file's path; the offending elements are kept as in TriMesh's errors.
    """
    path = Path(path)
    kind = _file_type(path, file_type)
    if not path.exists():
        raise MeshError(f"{path}: no such file")
    if path.is_dir():
        raise MeshError(f"{path}: is a directory, not a mesh file")
    try:
        if kind in ("stl", "gltf", "glb"):
            if path.stat().st_size == 0:
                raise MeshError("the file is empty")
            vertices, corners, sizes = _read_with_trimesh(path, kind)
        else:
            data = path.read_bytes()
            if not data.strip():
                raise MeshError("the file is empty")
            vertices, corners, sizes = {"obj": _read_obj, "off": _read_off, "ply": _read_ply}[kind](data)
        return _mesh(vertices, corners, sizes, kind, merge)
    except MeshError as err:
        raise MeshError(f"{path}: {err}", vertices=err.vertices, faces=err.faces, edges=err.edges) from None
    except OSError as err:
        raise MeshError(f"{path}: cannot be read ({err.strerror or err})") from None


def save_mesh(mesh: TriMesh, path, file_type: str | None = None) -> None:
    """Write a mesh's vertices and faces, in order, to an OBJ, PLY, OFF, STL, glTF or GLB file.

    The file is written next to its target and renamed over it, so it is either complete or untouched.
    OBJ and OFF (text with 17 significant digits) and PLY (binary float64) round-trip the coordinates
    exactly. glTF/GLB store float32 coordinates. STL stores float32 coordinates as a triangle soup
    (vertices no face uses are lost); read it back with ``load_mesh(path, merge=True)``, which numbers
    the vertices in order of first use.

    Parameters
    ----------
    mesh : TriMesh
    path : str or os.PathLike
    file_type : str, optional
        As for :func:`load_mesh`; by default from the extension.

    Raises
    ------
    MeshError
        For an unknown file type (or STL and glTF without trimesh installed).
    OSError
        If the file cannot be written.
    """
    if not isinstance(mesh, TriMesh):
        raise TypeError(f"save_mesh needs a TriMesh, got {type(mesh).__name__}")
    path = Path(path)
    kind = _file_type(path, file_type)
    if kind == "obj":
        write_atomically(path, _obj_text(mesh))
    elif kind == "off":
        write_atomically(path, _off_text(mesh))
    elif kind == "ply":
        write_atomically(path, _ply_bytes(mesh))
    else:
        try:
            trimesh = _import_trimesh(kind)
        except MeshError as err:
            raise MeshError(f"{path}: {err}") from None
        ours = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
        if kind == "gltf":
            files = trimesh.exchange.gltf.export_gltf(trimesh.Scene(ours), embed_buffers=True)
            write_atomically(path, files["model.gltf"].decode("utf-8"))
        else:
            write_atomically(path, ours.export(file_type=kind))


# ------------------------------------------------------------------------------------------------ common


def _file_type(path: Path, file_type: str | None) -> str:
    name = (file_type if file_type is not None else path.suffix).lower()
    kind = FILE_TYPES.get(name if name.startswith(".") else f".{name}")
    if kind is None:
        what = f"file type {file_type!r}" if file_type is not None else f"extension {path.suffix!r}"
        raise MeshError(
            f"{path}: unknown mesh {what}; use one of {', '.join(FILE_TYPES)} (or pass file_type)"
        )
    return kind


def _mesh(vertices: np.ndarray, corners: np.ndarray, sizes: np.ndarray, kind: str, merge: bool) -> TriMesh:
    """The TriMesh of a file's vertices and polygons (flat corner indices and corner counts)."""
    if sizes.size == 0:
        if len(vertices):
            raise MeshError(f"the file holds {len(vertices)} vertices but no faces (a point cloud)")
        raise MeshError("the file holds no vertices and no faces")
    bad = np.flatnonzero(~np.all(np.isfinite(vertices), axis=1))
    if bad.size:
        raise MeshError(f"vertices {describe_ids(bad)} have NaN or infinite coordinates", vertices=bad)

    def repeats() -> bool:
        return len(np.unique(vertices, axis=0)) < len(vertices)

    if kind == "stl" and not merge and repeats():
        raise MeshError(
            "STL stores every triangle with its own three corners, so its triangles share no vertices; "
            "pass merge=True to join corners with equal coordinates"
        )
    bad = np.flatnonzero((corners < 0) | (corners >= len(vertices)))
    if bad.size:
        raise MeshError(
            f"faces use vertex indices {describe_ids(corners[bad])} outside 0..{len(vertices) - 1} (the file "
            f"has {len(vertices)} vertices)"
        )
    if merge:
        vertices, corners = _merge(vertices, corners)
    try:
        if np.all(sizes == 3):
            return TriMesh(vertices, corners.reshape(-1, 3))
        return TriMesh.from_polygons(vertices, (corners, sizes))
    except MeshError as err:
        if not merge and repeats():
            hint = "; the file repeats vertex positions, which merge=True joins"
            raise MeshError(f"{err}{hint}", vertices=err.vertices, faces=err.faces, edges=err.edges) from None
        raise


def _merge(vertices: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Join vertices with equal coordinates, numbered in order of first occurrence."""
    _, first, inverse = np.unique(vertices, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    return vertices[first[order]], rank[inverse.reshape(-1)][corners]


def _text(data: bytes, what: str) -> str:
    """The file's text; past a UTF-8 byte-order mark, which Windows editors write before the first line."""
    if b"\0" in data:
        raise MeshError(f"the file holds binary data, not {what} text")
    return data.decode("utf-8-sig", errors="replace")


def _import_trimesh(kind: str):
    """trimesh, imported on first use (it is slow to import, and Blender's extension lacks it)."""
    try:
        import trimesh
    except ImportError:
        raise MeshError(
            f"{kind.upper()} files are read and written through trimesh, which is not installed "
            "(pip install trimesh)"
        ) from None
    return trimesh


# ------------------------------------------------------------------------------------------------ OBJ


def _read_obj(data: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices, flat polygon corners and corner counts of the ``v`` and ``f`` records, in file order."""
    text = _text(data, "OBJ").replace("\\\r\n", " ").replace("\\\n", " ")
    vertices: list[list[float]] = []
    corners: list[int] = []
    sizes: list[int] = []
    for number, line in enumerate(text.splitlines(), 1):
        fields = line.split("#", 1)[0].split()
        if not fields:
            continue
        if fields[0] == "v":
            try:
                if len(fields) < 4:
                    raise ValueError
                vertices.append([float(x) for x in fields[1:4]])
            except ValueError:
                raise MeshError(
                    f"line {number}: a vertex needs three numbers, got {line.strip()!r}"
                ) from None
        elif fields[0] == "f":
            if len(fields) < 4:
                raise MeshError(f"line {number}: a face needs at least three corners, got {line.strip()!r}")
            count = len(vertices)
            for ref in fields[1:]:
                try:
                    k = int(ref.split("/", 1)[0])
                except ValueError:
                    raise MeshError(f"line {number}: unreadable face corner {ref!r}") from None
                if k == 0:
                    raise MeshError(f"line {number}: vertex index 0 (OBJ counts vertices from 1)")
                corners.append(k - 1 if k > 0 else count + k)  # negative: relative to the last vertex
            sizes.append(len(fields) - 1)
    return (
        np.array(vertices, dtype=np.float64).reshape(-1, 3),
        np.array(corners, dtype=np.int64),
        np.array(sizes, dtype=np.int64),
    )


def _obj_text(mesh: TriMesh) -> str:
    lines = [f"# {mesh.n_vertices} vertices, {mesh.n_faces} triangles"]
    lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in mesh.vertices.tolist()]
    lines += [f"f {a} {b} {c}" for a, b, c in (mesh.faces + 1).tolist()]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------------------ OFF


def _read_off(data: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rows = [line.split("#", 1)[0].split() for line in _text(data, "OFF").splitlines()]
    rows = [row for row in rows if row]
    if not rows or not _OFF_HEADER.fullmatch(rows[0][0]):
        found = rows[0][0][:20] if rows else ""
        raise MeshError(f"not an OFF file: it starts with {found!r}, not 'OFF'")
    if len(rows[0]) > 1:  # "OFF n m e" on one line
        counts, rows = rows[0][1:], rows[1:]
    else:
        counts, rows = (rows[1] if len(rows) > 1 else []), rows[2:]
    try:
        n_vertices, n_faces = int(counts[0]), int(counts[1])
        if n_vertices < 0 or n_faces < 0:
            raise ValueError
    except (IndexError, ValueError):
        raise MeshError(f"the OFF counts line must give the vertex and face counts, got {counts}") from None
    if len(rows) < n_vertices + n_faces:
        raise MeshError(
            f"the file is truncated: it announces {n_vertices} vertices and {n_faces} faces but has "
            f"{len(rows)} lines of them"
        )
    try:
        vertices = np.array([row[:3] for row in rows[:n_vertices]], dtype=np.float64).reshape(-1, 3)
    except ValueError:
        raise MeshError("a vertex line does not hold three numbers") from None
    corners: list[str] = []
    sizes: list[int] = []
    for i, row in enumerate(rows[n_vertices : n_vertices + n_faces]):
        try:
            size = int(row[0])
        except ValueError:
            raise MeshError(f"face {i}: unreadable corner count {row[0]!r}") from None
        if size < 3 or len(row) < size + 1:
            raise MeshError(f"face {i}: needs at least three corners and as many indices as it announces")
        corners += row[1 : size + 1]
        sizes.append(size)
    try:
        flat = np.array(corners, dtype=np.int64)
    except ValueError:
        raise MeshError("a face holds an index that is not an integer") from None
    return vertices, flat, np.array(sizes, dtype=np.int64)


def _off_text(mesh: TriMesh) -> str:
    lines = ["OFF", f"{mesh.n_vertices} {mesh.n_faces} 0"]
    lines += [f"{x!r} {y!r} {z!r}" for x, y, z in mesh.vertices.tolist()]
    lines += [f"3 {a} {b} {c}" for a, b, c in mesh.faces.tolist()]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------------------ PLY


def _ply_header(data: bytes) -> tuple[str, list[tuple[str, int, list[tuple[str, str, str | None]]]], int]:
    """Format, elements (name, count, properties (name, value type, list count type or None)) and the
    offset of the body."""
    if not data.startswith(b"ply"):
        raise MeshError("not a PLY file: it does not start with 'ply'")
    end = re.search(rb"end_header[ \t]*\r?\n", data)
    if end is None:
        raise MeshError("the PLY header has no end_header line (is the file truncated?)")
    fmt = None
    elements: list[tuple[str, int, list[tuple[str, str, str | None]]]] = []
    for line in data[: end.start()].decode("ascii", errors="replace").splitlines()[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        try:
            if words[0] == "format" and words[1] in ("ascii", "binary_little_endian", "binary_big_endian"):
                fmt = words[1]
            elif words[0] == "element" and int(words[2]) >= 0:
                elements.append((words[1], int(words[2]), []))
            elif words[0] == "property" and words[1] == "list":
                elements[-1][2].append((words[4], _PLY_TYPES[words[3]], _PLY_TYPES[words[2]]))
            elif words[0] == "property":
                elements[-1][2].append((words[2], _PLY_TYPES[words[1]], None))
            else:
                raise ValueError
        except (IndexError, KeyError, ValueError):
            raise MeshError(f"unreadable PLY header line {line.strip()!r}") from None
    if fmt is None:
        raise MeshError("the PLY header has no (known) format line")
    return fmt, elements, end.end()


def _read_ply(data: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    fmt, elements, body = _ply_header(data)
    read = _ply_ascii_element if fmt == "ascii" else _ply_binary_element
    if fmt == "ascii":
        # One record a line, as the PLY writers (MeshLab, Blender) write them and as happly and trimesh read
        # them; numbered as the file's lines, for errors.
        state = {"lines": data[body:].splitlines(), "line": 0, "first": data[:body].count(b"\n") + 1}
    else:
        state = {"offset": body}
    state["endian"] = ">" if fmt == "binary_big_endian" else "<"
    vertices = np.empty((0, 3))
    corners, sizes = np.empty(0, np.int64), np.empty(0, np.int64)
    for name, count, properties in elements:
        names = [p[0] for p in properties]
        if name == "vertex":
            if not {"x", "y", "z"} <= set(names):
                raise MeshError("the PLY vertex element has no x, y and z properties")
            columns = read(data, state, name, count, properties, ["x", "y", "z"])
            vertices = np.stack([columns["x"], columns["y"], columns["z"]], 1).astype(np.float64)
        elif name == "face":
            index = next((n for n in _PLY_INDEX_NAMES if n in names), None)
            if index is None or properties[names.index(index)][2] is None:
                raise MeshError("the PLY face element has no vertex_indices list")
            values, sizes = read(data, state, name, count, properties, [index])[index]
            if values.dtype.kind == "f" and np.any(values != np.round(values)):
                raise MeshError("the PLY faces hold vertex indices that are not integers")
            corners = values.astype(np.int64)
        elif properties or fmt == "ascii":  # an ASCII record without properties is a (blank) line
            read(data, state, name, count, properties, [])
    return vertices, corners, sizes


def _ply_ascii_element(data, state, name, count, properties, wanted):
    """Read one element of an ASCII PLY body; returns the wanted properties (lists as (values, sizes)).

    Each record is one line, read as happly (geometry-central's reader) and trimesh read it: the declared
    properties from the start of the line, values after them ignored (MeshLab writes per-face values its
    header does not declare: trimesh's ``models/fuze_ascii.ply`` has six more on every face line), blank
    lines before a record skipped (as happly does). A line with fewer values than its properties take is
    an error naming the element and the line. References: happly.h ``parseASCII`` (nmwsharp/happly at
    88f7972, geometry-central's ``deps/happly``, lines 1845-1862: a ``getline`` per record, empty lines
    skipped, each property's ``parseNext`` taking tokens of that line only) and trimesh/exchange/ply.py
    ``_ply_ascii`` (lines 868-882: ``splitlines``, one array per line, ``length`` lines per element) with
    ``_load_element_single`` / ``_load_element_different`` (columns from the start of each row).
    """
    lines, at = state["lines"], state["line"]
    rows: list[list[bytes]] = []
    line_of: list[int] = []
    while len(rows) < count:
        if at == len(lines):
            raise MeshError(f"the PLY file is truncated: its {name} element ends early")
        words = lines[at].split()
        if words or not properties:
            rows.append(words)
            line_of.append(state["first"] + at)
        at += 1
    state["line"] = at
    lengths = np.fromiter(map(len, rows), np.int64, count)
    row_start = np.cumsum(lengths) - lengths
    tokens = np.empty(int(lengths.sum()), object)
    tokens[:] = [word for words in rows for word in words]

    def numbers_at(where: np.ndarray) -> np.ndarray:
        try:
            return tokens[where].astype(np.float64)
        except ValueError:
            bad = next(int(i) for i in where if not _is_number(tokens[i]))
            row = int(np.searchsorted(row_start, bad, "right")) - 1
            word = tokens[bad].decode("ascii", errors="replace")
            raise MeshError(
                f"the PLY {name} element holds a value that is not a number, {word!r}, on line {line_of[row]}"
            ) from None

    def too_short(rows_short: np.ndarray) -> None:
        if rows_short.any():
            row = int(np.argmax(rows_short))
            raise MeshError(
                f"the PLY {name} element's line {line_of[row]} holds {lengths[row]} values, fewer than its "
                f"properties ({', '.join(p[0] for p in properties)}) take"
            )

    out = {}
    position = np.zeros(count, np.int64)  # where each row's next property starts
    for prop, value_type, count_type in properties:
        size, first = np.ones(count, np.int64), position
        if count_type is not None:
            too_short(position >= lengths)
            size, first = numbers_at(row_start + position), position + 1
            bad = (size != np.round(size)) | (size < 0)
            if bad.any():
                raise MeshError(
                    f"the PLY {name} element's line {line_of[int(np.argmax(bad))]} holds a list length that "
                    "is negative or not a whole number"
                )
        too_short(first + size > lengths)  # in float64 still: a huge list length cannot wrap around
        size = size.astype(np.int64)
        if prop in wanted:
            within = np.arange(int(size.sum())) - np.repeat(np.cumsum(size) - size, size)
            values = _ply_cast(numbers_at(np.repeat(row_start + first, size) + within), value_type, name)
            out[prop] = values if count_type is None else (values, size)
        position = first + size
    return out


def _is_number(word: bytes) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True


def _ply_cast(values: np.ndarray, value_type: str, name: str) -> np.ndarray:
    """ASCII values as their declared type (a float property holds float32 values, as in binary files)."""
    if value_type[0] in "iu" and np.any(values != np.round(values)):
        raise MeshError(f"the PLY {name} element holds a non-integer value for an integer property")
    return values.astype(value_type)


def _ply_binary_element(data, state, name, count, properties, wanted):
    """Read one element of a binary PLY body; returns the wanted properties (lists as (values, sizes))."""
    endian, start = state["endian"], state["offset"]
    truncated = MeshError(f"the PLY file is truncated: its {name} element ends early")
    if count > len(data) - start:  # every row takes at least a byte
        raise truncated
    if all(p[2] is None for p in properties):
        dtype = np.dtype([(f"p{i}", endian + p[1]) for i, p in enumerate(properties)])
        if start + count * dtype.itemsize > len(data):
            raise truncated
        rows = np.frombuffer(data, dtype, count, start)
        state["offset"] = start + count * dtype.itemsize
        return {p[0]: rows[f"p{i}"] for i, p in enumerate(properties) if p[0] in wanted}
    # With lists, rows differ in length: find where each wanted value starts (one pass over the rows,
    # reading only the list counts), then gather the values at once.
    unpack = {p[2]: struct.Struct(endian + _STRUCT_CODES[p[2]]).unpack_from for p in properties if p[2]}
    starts = {p[0]: np.empty(count, np.int64) for p in properties if p[0] in wanted}
    sizes = {p[0]: np.ones(count, np.int64) for p in properties if p[0] in wanted}
    offset = start
    try:
        for row in range(count):
            for prop, value_type, count_type in properties:
                size = 1
                if count_type is not None:
                    size = int(unpack[count_type](data, offset)[0])
                    offset += int(count_type[1])
                    if size < 0:
                        raise MeshError(f"the PLY {name} element holds a list of negative length")
                if prop in starts:
                    starts[prop][row], sizes[prop][row] = offset, size
                offset += size * int(value_type[1])
    except struct.error:
        raise truncated from None
    if offset > len(data):
        raise truncated
    state["offset"] = offset
    buffer = np.frombuffer(data, np.uint8)
    out = {}
    for prop, first in starts.items():
        value_type = next(p[1] for p in properties if p[0] == prop)
        width, size = int(value_type[1]), sizes[prop]
        within = np.arange(int(size.sum())) - np.repeat(np.cumsum(size) - size, size)
        at = np.repeat(first, size) + within * width
        values = buffer[at[:, None] + np.arange(width)].view(endian + value_type).reshape(-1)
        is_list = next(p[2] for p in properties if p[0] == prop) is not None
        out[prop] = (values, size) if is_list else values
    return out


def _ply_bytes(mesh: TriMesh) -> bytes:
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {mesh.n_vertices}\nproperty double x\nproperty double y\nproperty double z\n"
        f"element face {mesh.n_faces}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    faces = np.empty(mesh.n_faces, dtype=[("count", "u1"), ("index", "<i4", (3,))])
    faces["count"] = 3
    faces["index"] = mesh.faces
    return header.encode("ascii") + mesh.vertices.astype("<f8").tobytes() + faces.tobytes()


# ------------------------------------------------------------------------------------------------ trimesh


def _read_with_trimesh(path: Path, kind: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices and triangles of an STL or glTF/GLB file's one mesh, as trimesh reads them."""
    trimesh = _import_trimesh(kind)
    if kind == "gltf":  # trimesh reports malformed JSON as a missing "model.gltf"
        try:
            json.loads(path.read_bytes())
        except ValueError as err:
            raise MeshError(f"not a glTF file: its JSON is malformed ({err})") from None
    try:
        scene = trimesh.load_scene(str(path), file_type=kind, process=False)
    except ModuleNotFoundError as err:  # trimesh reads text that is not UTF-8 with an optional module
        raise MeshError(
            f"trimesh cannot read it as {kind.upper()}: it is not complete binary data, and it is not UTF-8 "
            f"text ('{err.name}', which trimesh would guess its encoding with, is not installed)"
        ) from err
    except Exception as err:
        raise MeshError(f"trimesh cannot read it as {kind.upper()} ({type(err).__name__}: {err})") from err
    geometry = scene.geometry
    if not geometry:
        raise MeshError(f"trimesh finds no mesh in it (is it a complete {kind.upper()} file?)")
    placed = [(node, *scene.graph[node]) for node in scene.graph.nodes_geometry]
    if len(geometry) > 1:
        names = ", ".join(f"{name!r} ({type(g).__name__})" for name, g in geometry.items())
        raise MeshError(
            f"the file holds {len(geometry)} geometries ({names}); load_mesh reads a file with one mesh, "
            "because separate meshes number their vertices separately and exporters do not keep their "
            "order: join them into one mesh before exporting"
        )
    if len(placed) != 1:
        (name,) = geometry
        raise MeshError(
            f"the file places its mesh {name!r} {len(placed)} times; load_mesh reads a mesh placed once "
            "(each copy would need its own vertex numbering)"
        )
    _, transform, name = placed[0]
    mesh = geometry[name]
    if not isinstance(mesh, trimesh.Trimesh):
        count = len(getattr(mesh, "vertices", ()))
        raise MeshError(
            f"the file's geometry {name!r} is a {type(mesh).__name__} of {count} points, not a mesh"
        )
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    transform = np.asarray(transform, dtype=np.float64)
    if not np.array_equal(transform, np.eye(4)):
        vertices = vertices @ transform[:3, :3].T + transform[:3, 3]
    faces = np.asarray(mesh.faces, dtype=np.int64)
    return vertices, faces.reshape(-1), np.full(len(faces), 3, np.int64)
