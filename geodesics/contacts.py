"""Sets of named contact patches on one mesh: hierarchy, pairing and the JSON contact file.

Parenting (Contact Edit §4.3.4) links a child's first axis point to its parent's by a geodesic, stored
intrinsically (its length, the angle it leaves at relative to the parent's axis, and the child axis's
angle relative to where the link arrives), so editing a parent re-traces its children with it.

Pairs name each patch's counterpart in another set (a hand patch and the object patch it touches).

The contact file (JSON, ``format: contact-edit/contacts``, version 1) stores everything intrinsically
(faces and barycentric coordinates) plus the positions at save time, which are used only to remap the
file onto a different mesh when asked to. It is validated on load.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from .axis import Axis
from .errors import ContactError, MeshError
from .files import read_json, write_atomically
from .maps import geodesic_path
from .mesh import TriMesh
from .patch import ContactPatch
from .points import SurfacePoints
from .trace import exp_map

FORMAT = "contact-edit/contacts"
VERSION = 1


@dataclass(frozen=True)
class Link:
    """How a child patch hangs off its parent: the geodesic between their first axis points.

    Attributes
    ----------
    parent : str
    length : float
    leave : complex
        The link's initial direction relative to the parent axis's initial direction.
    arrive : complex
        The child axis's initial direction relative to the link's arrival direction.
    """

    parent: str
    length: float
    leave: complex
    arrive: complex

    def mirrored(self) -> Link:
        return Link(self.parent, self.length, np.conj(self.leave), np.conj(self.arrive))

    def follow(self, parent_axis: Axis) -> tuple[SurfacePoints, complex]:
        """Where the child axis starts, and its initial direction, for a parent at ``parent_axis``."""
        trace = exp_map(parent_axis.mesh, parent_axis.start, self.length * parent_axis.direction * self.leave)
        if trace.hit_boundary[0]:
            raise ContactError(
                f"the link from '{self.parent}' to a child patch runs off the surface's boundary after "
                f"{trace.lengths[0]:.4g} of {self.length:.4g}"
            )
        return trace.points, complex(trace.directions[0] * self.arrive)


class ContactSet:
    """Named contact patches on one mesh, with parent links and pairs. Every change returns a new set.

    Parameters
    ----------
    mesh : TriMesh
    patches : mapping of name -> ContactPatch, optional
    links : mapping of child name -> Link, optional
    pairs : mapping of name -> name of the counterpart patch in another set, optional
    """

    def __init__(
        self,
        mesh: TriMesh,
        patches: Mapping[str, ContactPatch] | None = None,
        links: Mapping[str, Link] | None = None,
        pairs: Mapping[str, str] | None = None,
    ):
        patches, links, pairs = dict(patches or {}), dict(links or {}), dict(pairs or {})
        for name, patch in patches.items():
            if not isinstance(name, str) or not name:
                raise ContactError(f"patch names must be non-empty strings, got {name!r}")
            if patch.mesh is not mesh:
                raise ContactError(f"patch '{name}' lies on another mesh than the set")
        for child, link in links.items():
            for name in (child, link.parent):
                if name not in patches:
                    raise ContactError(f"link refers to a patch '{name}' that is not in the set")
        for name in pairs:
            if name not in patches:
                raise ContactError(f"pair refers to a patch '{name}' that is not in the set")
        self.mesh = mesh
        self.patches = MappingProxyType(patches)
        self.links = MappingProxyType(links)
        self.pairs = MappingProxyType(pairs)
        for child in links:
            self._ancestors(child)  # rejects cycles

    # ------------------------------------------------------------------ access

    def __len__(self) -> int:
        return len(self.patches)

    def __iter__(self):
        return iter(self.patches)

    def __contains__(self, name) -> bool:
        return name in self.patches

    def __getitem__(self, name: str) -> ContactPatch:
        try:
            return self.patches[name]
        except KeyError:
            raise ContactError(
                f"there is no patch named '{name}' (patches: {', '.join(self.patches)})"
            ) from None

    def __repr__(self) -> str:
        return f"ContactSet({len(self)} patches: {', '.join(self.patches)})"

    def children(self, name: str) -> list[str]:
        return [child for child, link in self.links.items() if link.parent == name]

    def descendants(self, name: str) -> list[str]:
        """All patches below ``name``, parents before their children."""
        out = []
        for child in self.children(name):
            out += [child, *self.descendants(child)]
        return out

    def _ancestors(self, name: str) -> list[str]:
        seen = []
        while name in self.links:
            name = self.links[name].parent
            if name in seen:
                raise ContactError(f"parent links form a cycle through '{name}'")
            seen.append(name)
        return seen

    def _with(self, patches=None, links=None, pairs=None) -> ContactSet:
        return ContactSet(
            self.mesh,
            self.patches if patches is None else patches,
            self.links if links is None else links,
            self.pairs if pairs is None else pairs,
        )

    # ------------------------------------------------------------------ changes

    def add(self, name: str, patch: ContactPatch) -> ContactSet:
        if name in self.patches:
            raise ContactError(f"a patch named '{name}' already exists")
        return self._with(patches={**self.patches, name: patch})

    def remove(self, name: str) -> ContactSet:
        """Remove a patch; its children stay where they are, without a parent; pairs to it go."""
        self[name]
        patches = {k: v for k, v in self.patches.items() if k != name}
        links = {k: v for k, v in self.links.items() if k != name and v.parent != name}
        pairs = {k: v for k, v in self.pairs.items() if k != name}
        return self._with(patches, links, pairs)

    def parent(self, child: str, parent: str) -> ContactSet:
        """Link ``child`` under ``parent`` (a geodesic between their first axis points, §4.3.4)."""
        c, p = self[child], self[parent]
        if child == parent or child in self._ancestors(parent):
            raise ContactError(f"'{parent}' cannot become the parent of '{child}': that would make a cycle")
        path = geodesic_path(self.mesh, p.axis.start, c.axis.start)
        if path.length == 0:
            raise ContactError(f"'{child}' and '{parent}' start at the same point; move one before linking")
        link = Link(
            parent,
            path.length,
            path.initial_direction / p.axis.direction,
            c.axis.direction / path.final_direction,
        )
        return self._with(links={**self.links, child: link})

    def unparent(self, child: str) -> ContactSet:
        self[child]
        return self._with(links={k: v for k, v in self.links.items() if k != child})

    def pair(self, name: str, counterpart: str) -> ContactSet:
        """Record that patch ``name`` touches patch ``counterpart`` of another set."""
        self[name]
        return self._with(pairs={**self.pairs, name: counterpart})

    def replace(self, name: str, patch: ContactPatch) -> ContactSet:
        """Put ``patch`` in place of ``name``, carrying its descendants along their links."""
        if patch.mesh is not self.mesh:
            raise ContactError(f"the new patch '{name}' lies on another mesh than the set")
        patches = dict(self.patches)
        patches[name] = patch
        for child in self.descendants(name):
            link = self.links[child]
            start, direction = link.follow(patches[link.parent].axis)
            old = patches[child]
            patches[child] = old.moved_to(old.axis.trace(self.mesh, start, direction))
        return self._with(patches=patches)

    def translate(self, name: str, to: SurfacePoints) -> ContactSet:
        return self.replace(name, self[name].translate(to))

    def rotate(self, name: str, angle: float) -> ContactSet:
        return self.replace(name, self[name].rotate(angle))

    def bend(self, name: str, index: int, angle: float) -> ContactSet:
        return self.replace(name, self[name].bend(index, angle))

    def transfer(
        self,
        name: str,
        target: ContactSet,
        start: SurfacePoints,
        direction: complex,
        rename: Callable[[str], str] = lambda name: name,
        hierarchy: bool = True,
    ) -> tuple[ContactSet, ContactSet]:
        """Transfer patch ``name`` and (if ``hierarchy``) its descendants onto ``target``'s mesh as
        mirror images (§5.3), pairing each with its transfer.

        Returns the updated (this set, target set). Nothing changes if any transfer fails.
        """
        self[name]  # a clear error for an unknown name
        names = [name, *self.descendants(name)] if hierarchy else [name]
        taken = [rename(n) for n in names if rename(n) in target]
        if taken:
            raise ContactError(f"the target already has patches named {', '.join(taken)}")
        moved = {rename(name): self[name].transfer(target.mesh, start, direction)}
        links = {}
        for child in names[1:]:
            link = self.links[child].mirrored()
            child_start, child_direction = link.follow(moved[rename(link.parent)].axis)
            moved[rename(child)] = self[child].transfer(target.mesh, child_start, child_direction)
            links[rename(child)] = Link(rename(link.parent), link.length, link.leave, link.arrive)
        target = target._with(
            patches={**target.patches, **moved},
            links={**target.links, **links},
            pairs={**target.pairs, **{rename(n): n for n in names}},
        )
        source = self._with(pairs={**self.pairs, **{n: rename(n) for n in names}})
        return source, target

    # ------------------------------------------------------------------ files

    def to_dict(self) -> dict:
        """The contact file's content (JSON-ready)."""
        patches = []
        for name, patch in self.patches.items():
            link = self.links.get(name)
            patches.append({
                "name": name,
                "points": _points_dict(patch.points),
                "positions": patch.positions().tolist(),
                "axis": {
                    "points": _points_dict(patch.axis.points),
                    "positions": patch.axis.points.positions(self.mesh).tolist(),
                    "lengths": patch.axis.lengths.tolist(),
                    "turning": _complex_list(patch.axis.turning),
                    "tangents": _complex_list(patch.axis.tangents),
                },
                "binding": patch.binding.tolist(),
                "coords": _complex_list(patch.coords),
                "parent": link.parent if link else None,
                "link": None if link is None else {
                    "length": link.length,
                    "leave": _complex_list([link.leave])[0],
                    "arrive": _complex_list([link.arrive])[0],
                },
                "pair": self.pairs.get(name),
            })  # fmt: skip
        return {
            "format": FORMAT,
            "version": VERSION,
            "mesh": {
                "vertices": self.mesh.n_vertices,
                "faces": self.mesh.n_faces,
                "hash": self.mesh.topology_hash,
            },
            "patches": patches,
        }

    def save(self, path) -> None:
        """Write the contact file atomically (a complete file or none; never half a file)."""
        write_atomically(path, json.dumps(self.to_dict(), indent=1))

    @classmethod
    def load(cls, path, mesh: TriMesh, remap: bool = False) -> ContactSet:
        """Read a contact file for ``mesh``.

        A file made for another mesh (different topology) is refused unless ``remap`` is true; then each
        patch is projected onto ``mesh`` by its saved positions and parameterized anew.
        """
        data = read_json(path, "contact file", ContactError)
        return cls.from_dict(data, mesh, remap=remap, source=str(path))

    @classmethod
    def from_dict(cls, data, mesh: TriMesh, remap: bool = False, source: str = "contact data") -> ContactSet:
        """Validate a contact file's content and build the set (see :meth:`load`)."""
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise ContactError(f'{source}: not a contact file (expected "format": "{FORMAT}")')
        if type(data.get("version")) is not int or data["version"] != VERSION:  # true == 1 in Python
            raise ContactError(
                f"{source}: version {data.get('version')!r} is not supported (this build reads {VERSION})"
            )
        info = _field(data, "mesh", dict, source)
        same = (
            info.get("vertices") == mesh.n_vertices
            and info.get("faces") == mesh.n_faces
            and info.get("hash") == mesh.topology_hash
        )
        if not same and not remap:
            raise ContactError(
                f"{source}: made for another mesh ({info.get('vertices')} vertices, "
                f"{info.get('faces')} faces, hash {str(info.get('hash'))[:12]}…), not this one "
                f"({mesh.n_vertices} vertices, {mesh.n_faces} faces, hash {mesh.topology_hash[:12]}…); "
                "load it with remap to project it"
            )
        entries = _field(data, "patches", list, source)
        patches, links, pairs = {}, {}, {}
        for i, entry in enumerate(entries):
            where = f"{source}: patch {i}"
            if not isinstance(entry, dict):
                raise ContactError(f"{where}: expected an object")
            name = _field(entry, "name", str, where)
            where = f"{source}: patch '{name}'"
            if name in patches:
                raise ContactError(f"{where}: the name is used twice")
            try:
                patches[name] = _patch(entry, mesh, remap=not same)
            except (MeshError, ContactError, TypeError, ValueError, KeyError) as err:
                raise ContactError(f"{where}: {err}") from None
            if entry.get("parent") is not None:
                links[name] = _link(entry, where)
            if entry.get("pair") is not None:
                pairs[name] = _field(entry, "pair", str, where)
        for child, link in links.items():
            if link.parent not in patches:
                raise ContactError(
                    f"{source}: patch '{child}' has a parent '{link.parent}' that is not in the file"
                )
        result = cls(mesh, patches, {}, pairs)
        if same:
            return cls(mesh, patches, links, pairs)
        for child, link in links.items():  # remapped: the links are measured anew on this mesh
            result = result.parent(child, link.parent)
        return result


def _points_dict(points: SurfacePoints) -> dict:
    return {"faces": points.faces.tolist(), "bary": points.bary.tolist()}


def _complex_list(values) -> list:
    values = np.asarray(values, dtype=np.complex128)
    return np.stack([values.real, values.imag], axis=-1).tolist()


def _field(entry: dict, key: str, kind, where: str):
    if key not in entry:
        raise ContactError(f"{where}: the field '{key}' is missing")
    value = entry[key]
    if not isinstance(value, kind) or isinstance(value, bool):
        raise ContactError(
            f"{where}: the field '{key}' should be a {kind.__name__}, got {type(value).__name__}"
        )
    return value


def _complex_array(values, where: str) -> np.ndarray:
    try:
        a = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        a = np.empty(0)
    if a.ndim != 2 or a.shape[1] != 2 or not np.all(np.isfinite(a)):
        raise ContactError(f"{where} must be a list of finite [real, imaginary] pairs")
    return a[:, 0] + 1j * a[:, 1]


def _indices(values, where: str) -> np.ndarray:
    """A JSON list of integers as int64, checked before numpy sees it: 1.5 or true would silently become
    an index, 2**70 would overflow."""
    if not isinstance(values, list) or not all(type(v) is int and -(2**63) <= v < 2**63 for v in values):
        raise ContactError(f"{where} must be a list of integer indices")
    return np.array(values, dtype=np.int64)


def _surface_points(data, mesh: TriMesh, where: str) -> SurfacePoints:
    if not isinstance(data, dict):
        raise ContactError(f"{where} must be an object with 'faces' and 'bary'")
    faces = _indices(_field(data, "faces", list, where), f"{where}.faces")
    points = SurfacePoints(faces, np.asarray(_field(data, "bary", list, where), dtype=np.float64))
    return points.validate(mesh)


def _patch(entry: dict, mesh: TriMesh, remap: bool) -> ContactPatch:
    axis_data = _field(entry, "axis", dict, "the patch")
    if remap:
        axis_points = SurfacePoints.nearest(mesh, np.asarray(axis_data["positions"], dtype=np.float64))
        points = SurfacePoints.nearest(mesh, np.asarray(entry["positions"], dtype=np.float64))
        return ContactPatch(mesh, points, Axis(mesh, axis_points))
    axis_points = _surface_points(axis_data["points"], mesh, "axis.points")
    points = _surface_points(entry["points"], mesh, "points")
    m, k = len(axis_points), len(points)
    lengths = np.asarray(axis_data["lengths"], dtype=np.float64)
    turning = _complex_array(axis_data["turning"], "axis.turning")
    tangents = _complex_array(axis_data["tangents"], "axis.tangents")
    binding = _indices(_field(entry, "binding", list, "the patch"), "binding")
    coords = _complex_array(entry["coords"], "coords")
    if m < 2 or lengths.shape != (m - 1,) or turning.shape != (m,) or tangents.shape != (m,):
        raise ContactError(
            f"the axis has {m} points but {lengths.size} lengths, {turning.size} turning angles "
            f"and {tangents.size} tangents (expected m-1, m, m with m >= 2)"
        )
    if not np.all(np.isfinite(lengths) & (lengths > 0)):
        raise ContactError("axis lengths must be positive and finite")
    if np.any(np.abs(np.abs(turning) - 1) > 1e-9) or np.any(np.abs(np.abs(tangents) - 1) > 1e-9):
        raise ContactError("axis turning angles and tangents must be unit complex numbers")
    if binding.shape != (k,) or coords.shape != (k,) or np.any((binding < 0) | (binding >= m)):
        raise ContactError(
            f"binding and coords must give one axis point index in 0..{m - 1} and one complex "
            f"number per patch point ({k})"
        )
    axis = Axis._embedded(mesh, axis_points, lengths, turning, tangents)
    patch = ContactPatch.__new__(ContactPatch)
    patch._set(mesh, points, axis, binding, coords)
    return patch


def _link(entry: dict, where: str) -> Link:
    parent = _field(entry, "parent", str, where)
    data = _field(entry, "link", dict, where)
    length = data.get("length")
    if not isinstance(length, (int, float)) or not np.isfinite(length) or length <= 0:
        raise ContactError(f"{where}: link.length must be a positive number")
    leave = _complex_array([data.get("leave")], f"{where}: link.leave")[0]
    arrive = _complex_array([data.get("arrive")], f"{where}: link.arrive")[0]
    return Link(parent, float(length), complex(leave), complex(arrive))
