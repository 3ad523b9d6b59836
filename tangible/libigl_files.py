"""libigl's matrix and skeleton files, ``.dmat`` and ``.tgf``, as the authors' rig reducer reads and writes
them (:mod:`tangible.rigreducer`), and the ``.obj`` mesh it is started on.

``.dmat`` (``readDMAT``/``writeDMAT``): an ASCII header ``cols rows`` then the values
column by column, whitespace-separated (written one per line, ``%.17g``, which round-trips float64); or
the binary variant: ``0 0`` (an empty ASCII matrix), a second header ``cols rows``, then ``cols · rows``
little-endian float64, column-major. ``.tgf``: node lines ``index x y z`` (1-based, in order; libigl
ignores anything after ``z`` and we read it as a label), a line starting with ``#``, edge lines
``a b [is_bone is_pseudo is_cage]`` (1-based node indices; libigl ignores what follows the integers), an
optional second ``#`` after which everything is ignored. libigl reads lines of up to 499 bytes.

Every reader names the file and the line (or byte offset) of what it refuses
(:class:`~tangible.errors.RigError`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import RigError

__all__ = [
    "TGF",
    "TGF_LINE_BYTES",
    "dmat_columns",
    "format_dmat",
    "format_tgf",
    "parse_dmat",
    "parse_tgf",
    "read_dmat",
    "read_tgf",
    "write_dmat",
    "write_obj",
    "write_tgf",
]

#: libigl's ``readTGF`` reads lines into a 500-byte buffer.
TGF_LINE_BYTES = 499

_NUMBER = r"[+-]?(?:(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?|inf(?:inity)?|nan)"
_NUMBER_RE = re.compile(_NUMBER, re.IGNORECASE)
_NUMBERS_RE = re.compile(rf"\s*(?:(?:{_NUMBER})(?:\s+|$))*", re.IGNORECASE)
_INT_RE = re.compile(r"[+-]?\d+")
_HEADER_RE = re.compile(rb"[ \t\r\n]*([0-9]+)[ \t]+([0-9]+)[ \t\r]*\n")
_MAX_HEADER_DIGITS = 12


# ================================================================== .dmat


def parse_dmat(data: bytes, name: str = "<dmat>") -> np.ndarray:
    """(rows, cols) float64: the matrix in the bytes of a ``.dmat`` file (ASCII or binary, see the module
    docstring), as its header gives its size.

    Raises
    ------
    RigError
        Naming ``name`` and the line (or byte offset) of a bad header, a value that is not a number, too
        few or too many values, or a truncated binary part.
    """
    if not isinstance(data, bytes | bytearray | memoryview):
        raise RigError(f"{name}: expected the file's bytes, got {type(data).__name__}")
    data = bytes(data)
    cols, rows, end = _dmat_header(data, 0, name, "line 1")
    if cols * rows == 0:
        rest = data[end:]
        if not rest.strip():
            return np.zeros((rows, cols))
        if cols or rows:
            raise RigError(
                f"{name}: a {rows} x {cols} matrix has no values, but the file goes on after line 1"
            )
        # The binary variant: "0 0", then the real header, then float64 column-major.
        cols, rows, end = _dmat_header(data, end, name, "the binary header (line 2)")
        size = cols * rows * 8
        body = data[end:]
        if len(body) != size:
            what = "truncated" if len(body) < size else "too long"
            raise RigError(
                f"{name}: binary part {what}: a {rows} x {cols} matrix needs {size} bytes after the "
                f"header, the file has {len(body)}"
            )
        return np.frombuffer(body, dtype="<f8").reshape(cols, rows).T.astype(np.float64)
    try:
        text = data[end:].decode("ascii")
    except UnicodeDecodeError as err:
        line = 2 + data[end : end + err.start].count(b"\n")
        raise RigError(f"{name}: line {line}: byte 0x{data[end + err.start]:02x} is not ASCII text") from None
    if not _NUMBERS_RE.fullmatch(text):
        for m in re.finditer(r"\S+", text):
            if not _NUMBER_RE.fullmatch(m.group()):
                line = 2 + text.count("\n", 0, m.start())
                raise RigError(f"{name}: line {line}: {_show(m.group())} is not a number")
    tokens = text.split()
    if len(tokens) != cols * rows:
        what = "truncated" if len(tokens) < cols * rows else "too many values"
        raise RigError(
            f"{name}: {what}: the header (line 1) announces {rows} rows x {cols} columns = {cols * rows} "
            f"values, the file has {len(tokens)}"
        )
    values = np.array([float(t) for t in tokens], dtype=np.float64)
    return values.reshape(cols, rows).T.copy()


def _dmat_header(data: bytes, start: int, name: str, where: str) -> tuple[int, int, int]:
    m = _HEADER_RE.match(data, start)
    if m is None or len(m.group(1)) > _MAX_HEADER_DIGITS or len(m.group(2)) > _MAX_HEADER_DIGITS:
        head = data[start : start + 40].split(b"\n")[0].strip()
        raise RigError(
            f"{name}: {where} should be '<columns> <rows>' (two non-negative integers and a line end), "
            f"got {_show(head.decode('latin-1'))}"
        )
    return int(m.group(1)), int(m.group(2)), m.end()


def _show(token: str, limit: int = 40) -> str:
    return repr(token if len(token) <= limit else token[:limit] + "…")


def format_dmat(matrix, *, binary: bool = False) -> bytes:
    """The bytes of a ``.dmat`` file holding ``matrix`` ((rows, cols), or (rows,) as a column), as libigl's
    ``writeDMAT`` writes it: ASCII with ``%.17g`` (exact for float64), or the binary variant."""
    W = np.asarray(matrix, dtype=np.float64)
    if W.ndim == 1:
        W = W[:, None]
    if W.ndim != 2:
        raise RigError(f"a .dmat file holds a matrix, got an array of shape {W.shape}")
    rows, cols = W.shape
    if binary:
        return b"0 0\n" + f"{cols} {rows}\n".encode() + W.T.astype("<f8").tobytes()
    lines = [f"{cols} {rows}", *(f"{v:.17g}" for v in W.T.ravel())]
    return ("\n".join(lines) + "\n").encode("ascii")


def read_dmat(path) -> np.ndarray:
    """(rows, cols) float64: the matrix in a ``.dmat`` file (see :func:`parse_dmat`)."""
    return parse_dmat(_read_bytes(path), str(path))


def write_dmat(path, matrix, *, binary: bool = False) -> None:
    """Write ``matrix`` ((rows, cols), or (rows,) as a column) to a ``.dmat`` file (:func:`format_dmat`)."""
    _write_bytes(path, format_dmat(matrix, binary=binary))


def _read_bytes(path) -> bytes:
    try:
        return Path(path).read_bytes()
    except OSError as err:
        raise RigError(f"{path}: cannot be read ({err.strerror or err})") from None


def _write_bytes(path, data: bytes) -> None:
    try:
        Path(path).write_bytes(data)
    except OSError as err:
        raise RigError(f"{path}: cannot be written ({err.strerror or err})") from None


# ================================================================== .tgf


@dataclass(frozen=True)
class TGF:
    """The contents of a ``.tgf`` file.

    Attributes
    ----------
    nodes : (n, 3) ndarray
        Node positions.
    edges : (m, 2) int ndarray
        Node indices (0-based) of each edge, first to second.
    flags : (m, 3) int ndarray
        libigl's ``is_bone``, ``is_pseudo``, ``is_cage`` flags of each edge (0 where the line has none).
    labels : tuple of str
        Per node, the text after its coordinates ("" for none).
    """

    nodes: np.ndarray
    edges: np.ndarray
    flags: np.ndarray
    labels: tuple[str, ...]

    @property
    def pseudo(self) -> np.ndarray:
        """(m,) bool: pseudo edges (flag ``is_pseudo`` = 1)."""
        return self.flags[:, 1] == 1


def parse_tgf(data: bytes | str, name: str = "<tgf>") -> TGF:
    """A :class:`TGF` from the contents of a ``.tgf`` file (see the module docstring).

    Blank lines are skipped. Stricter than libigl: node indices must be 1, 2, 3, … in order and
    coordinates finite numbers (libigl ignores the indices and would misread a file numbered otherwise).

    Raises
    ------
    RigError
        Naming ``name`` and the line.
    """
    if isinstance(data, bytes | bytearray | memoryview):
        try:
            text = bytes(data).decode("utf-8")
        except UnicodeDecodeError as err:
            line = 1 + bytes(data)[: err.start].count(b"\n")
            raise RigError(f"{name}: line {line}: not UTF-8 text") from None
    elif isinstance(data, str):
        text = data
    else:
        raise RigError(f"{name}: expected the file's bytes or text, got {type(data).__name__}")
    nodes: list[list[float]] = []
    labels: list[str] = []
    edges: list[list[int]] = []
    flags: list[list[int]] = []
    section = 0  # 0 nodes, 1 edges, 2 ignored
    for number, line in enumerate(text.split("\n"), start=1):
        if line.startswith("#"):
            section = min(section + 1, 2)
            continue
        if section == 2 or not line.strip():
            continue
        where = f"{name}: line {number}"
        if section == 0:
            m = re.match(r"\s*(\S+)\s+(\S+)\s+(\S+)\s+(\S+)(.*)$", line, re.DOTALL)
            if m is None:
                raise RigError(
                    f"{where}: a node line needs an index and three coordinates, got {_show(line)}"
                )
            index, *coords = m.group(1, 2, 3, 4)
            if not _INT_RE.fullmatch(index):
                raise RigError(f"{where}: node index {_show(index)} is not an integer")
            if int(index) != len(nodes) + 1:
                raise RigError(
                    f"{where}: node index {index}, expected {len(nodes) + 1} (nodes are numbered 1, 2, 3, … "
                    "in file order)"
                )
            for c in coords:
                if not _NUMBER_RE.fullmatch(c):
                    raise RigError(f"{where}: coordinate {_show(c)} is not a number")
            xyz = [float(c) for c in coords]
            if not np.all(np.isfinite(xyz)):
                raise RigError(f"{where}: node {index} has a non-finite coordinate")
            nodes.append(xyz)
            labels.append(m.group(5).strip())
        else:
            tokens = line.split()
            ints = []
            for t in tokens[:5]:
                if not _INT_RE.fullmatch(t) or len(t) > 12:
                    break
                ints.append(int(t))
            if len(ints) < 2:
                raise RigError(f"{where}: an edge line needs two node indices, got {_show(line)}")
            a, b = ints[:2]
            for i in (a, b):
                if not 1 <= i <= len(nodes):
                    raise RigError(f"{where}: edge node {i} is outside 1..{len(nodes)}")
            if a == b:
                raise RigError(f"{where}: edge from node {a} to itself")
            edges.append([a - 1, b - 1])
            flags.append([*ints[2:], 0, 0, 0][:3])
    return TGF(
        nodes=np.array(nodes, dtype=np.float64).reshape(-1, 3),
        edges=np.array(edges, dtype=np.int64).reshape(-1, 2),
        flags=np.array(flags, dtype=np.int64).reshape(-1, 3),
        labels=tuple(labels),
    )


def format_tgf(tgf: TGF) -> str:
    """The text of a ``.tgf`` file, laid out as libigl's ``writeTGF`` (``%.17g`` coordinates), with each
    node's label after its coordinates and each edge's flags when any is set."""
    nodes = np.asarray(tgf.nodes, dtype=np.float64)
    out = []
    for i, (p, label) in enumerate(zip(nodes, tgf.labels, strict=True)):
        line = f"{i + 1:4d} {p[0]:.17g} {p[1]:.17g} {p[2]:.17g}"
        out.append(f"{line} {label}" if label else line)
    out.append("#")
    for (a, b), f in zip(np.asarray(tgf.edges), np.asarray(tgf.flags), strict=True):
        line = f"{a + 1:4d} {b + 1:4d}"
        out.append(f"{line} {f[0]} {f[1]} {f[2]}" if np.any(f) else line)
    out.append("#")
    return "\n".join(out) + "\n"


def read_tgf(path) -> TGF:
    """The contents of a ``.tgf`` file (see :func:`parse_tgf`)."""
    return parse_tgf(_read_bytes(path), str(path))


def write_tgf(path, tgf: TGF) -> None:
    """Write a ``.tgf`` file (see :func:`format_tgf`)."""
    _write_bytes(path, format_tgf(tgf).encode("utf-8"))


def dmat_columns(path: Path) -> int | None:
    """The column count in a .dmat file's header, or None when the file is missing."""
    if not path.exists():
        return None
    head = _read_bytes(path)
    cols, rows, end = _dmat_header(head, 0, str(path), "line 1")
    if cols == rows == 0 and head[end:].strip():
        cols, rows, _ = _dmat_header(head, end, str(path), "the binary header (line 2)")
    return cols


def write_obj(path: Path, V: np.ndarray, F: np.ndarray) -> None:
    lines = [f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in np.asarray(V, dtype=np.float64)]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in np.asarray(F, dtype=np.int64)]
    _write_bytes(path, ("\n".join(lines) + "\n").encode("ascii"))
