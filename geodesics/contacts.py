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

import dataclasses
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
from .schema import Fields
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
        """The link of the mirror image: both directions conjugated."""
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

    def rename(self, old: str, new: str) -> ContactSet:
        """The same set with patch ``old`` called ``new`` (in its place in the order, its links and its
        pair kept)."""
        self[old]
        if not isinstance(new, str) or not new:
            raise ContactError(f"patch names must be non-empty strings, got {new!r}")
        if new != old and new in self.patches:
            raise ContactError(f"a patch named '{new}' already exists")

        def named(n: str) -> str:
            return new if n == old else n

        patches = {named(k): v for k, v in self.patches.items()}
        links = {named(k): dataclasses.replace(v, parent=named(v.parent)) for k, v in self.links.items()}
        pairs = {named(k): v for k, v in self.pairs.items()}
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
        scale: float = 1.0,
        mirror: bool = True,
    ) -> tuple[ContactSet, ContactSet]:
        """Transfer patch ``name`` and (if ``hierarchy``) its descendants onto ``target``'s mesh as
        mirror images (§5.3), pairing each with its transfer.

        ``scale`` is the length on ``target``'s mesh of a unit length on this set's (the two meshes'
        units differ when their objects are scaled differently), so that a transfer keeps the patches'
        true size. ``mirror=False`` transfers the patches themselves, not their mirror images: for
        meshes placed with opposite handedness (one object scaled by -1), whose mirror images are.

        Returns the updated (this set, target set). Nothing changes if any transfer fails.
        """
        self[name]  # a clear error for an unknown name
        if not (np.isfinite(scale) and scale > 0):
            raise ContactError(f"the transfer's scale must be a positive length ratio, not {scale!r}")
        names = [name, *self.descendants(name)] if hierarchy else [name]
        taken = [rename(n) for n in names if rename(n) in target]
        if taken:
            raise ContactError(f"the target already has patches named {', '.join(taken)}")

        def embed(patch: ContactPatch, at: SurfacePoints, direction: complex) -> ContactPatch:
            return patch.transfer(
                target.mesh, at, direction, axis_scale=scale, radial_scale=scale, mirror=mirror
            )

        moved = {rename(name): embed(self[name], start, direction)}
        links = {}
        for child in names[1:]:
            link = self.links[child].mirrored() if mirror else self.links[child]
            link = Link(link.parent, link.length * scale, link.leave, link.arrive)
            child_start, child_direction = link.follow(moved[rename(link.parent)].axis)
            moved[rename(child)] = embed(self[child], child_start, child_direction)
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
        file = Fields(data, source, ContactError, "a contact file (a JSON object)")
        file.header(FORMAT, VERSION, "contact file")
        info = file.object("mesh").data
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
        patches, links, pairs = {}, {}, {}
        for entry in file.objects("patches"):
            name = entry.string("name")
            entry = entry.renamed(f"{source}: patch '{name}'")
            if name in patches:
                entry.fail("the name is used twice")
            patches[name] = _patch(entry, mesh, remap=not same)
            if "parent" in entry:
                links[name] = _link(entry)
            if "pair" in entry:
                pairs[name] = entry.string("pair")
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


def _surface_points(data: Fields, mesh: TriMesh) -> SurfacePoints:
    faces, bary = data.indices("faces"), data.numbers("bary", (None, 3), finite=False)
    try:
        return SurfacePoints(faces, bary).validate(mesh)
    except MeshError as err:
        data.fail(str(err))


def _patch(entry: Fields, mesh: TriMesh, remap: bool) -> ContactPatch:
    axis = entry.object("axis")
    if remap:  # rebuilt from the saved positions
        axis_positions, positions = (
            axis.numbers("positions", (None, 3)),
            entry.numbers("positions", (None, 3)),
        )
        try:
            on_mesh = Axis(mesh, SurfacePoints.nearest(mesh, axis_positions))
            return ContactPatch(mesh, SurfacePoints.nearest(mesh, positions), on_mesh)
        except (MeshError, ContactError) as err:
            entry.fail(str(err))
    axis_points, points = (
        _surface_points(axis.object("points"), mesh),
        _surface_points(entry.object("points"), mesh),
    )
    lengths, turning, tangents = (
        axis.numbers("lengths", (None,)),
        axis.complex("turning"),
        axis.complex("tangents"),
    )
    binding, coords = entry.indices("binding"), entry.complex("coords")
    try:
        embedded = Axis.embedded(mesh, axis_points, lengths, turning, tangents)
        return ContactPatch.parameterized(embedded, points, binding, coords)
    except ContactError as err:
        entry.fail(str(err))


def _link(entry: Fields) -> Link:
    data = entry.object("link")
    length = data.number("length", positive=True)
    leave, arrive = (complex(*data.numbers(key, (2,))) for key in ("leave", "arrive"))
    return Link(entry.string("parent"), length, leave, arrive)
