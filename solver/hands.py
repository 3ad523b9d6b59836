"""Procedural rigged and skinned manipulators: a human hand, a witch's hand, an alien hand, a tentacle.

Each is box-modelled the way an artist would (see :mod:`solver.subdivision`): a palm block whose
knuckle faces are extruded into fingers ring by ring along the finger bones, a side face into the
thumb, the wrist face into a forearm stub; then two levels of Catmull-Clark subdivision. The cage's
vertices carry one-hot (or half-and-half at joints) bone weights, which the subdivision smooths into
skin weights that blend across each joint over about a bone's length and still sum to one.

Conventions (scale 1, metres, armature space): a right hand, wrist at the origin, fingers along +y,
palm facing -z, thumb on the -x side. Every bone's z axis points to its palm (flexion) side, so a
positive x rotation curls a finger into the palm and a positive z rotation spreads it towards -x
(the thumb side). The rest pose is a relaxed, slightly curled open hand. The tentacle lies along +y
from its base at the origin, its suction side facing -z.

Rigs: the root is the forearm (6 DOF) for the hands and the base for the tentacle; every other bone is a
3-DOF ball joint with anatomical limits. The human and witch hands have 17 bones (54 DOF), the alien
hand 13 (42 DOF), the tentacle 14 (45 DOF).

**Left hands** (``make_hand(kind, side="left")``) are the right ones reflected through the armature's
x = 0 plane (:func:`mirror_hand`: vertex x negated, triangles reversed so normals still point out, each
rest matrix ``S M S`` with ``S = diag(-1, 1, 1)``), as rigs of their own: a right pose ``θ`` corresponds
to the left pose :func:`mirror_theta` ``(θ)`` (root x location negated, every bone's y and z Euler
angles negated, x angles kept: ``S R S`` for ``R = Rz(c) Ry(b) Rx(a)`` is ``Rz(-c) Ry(-b) Rx(a)``), with
limits mirrored alike, so flexion stays a positive x rotation. A hand is named by a kind string: the
kind for the right hand, the kind and :data:`LEFT` (``"human-left"``) for its mirror image, as a
motion's ``source_kind`` and :class:`solver.retarget.HandSpec` name it; :func:`hand_from_kind` builds
either.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from geodesics import SurfacePoints, TriMesh

from .errors import SolverError
from .rig import Rig, SkinnedMesh
from .subdivision import Cage, catmull_clark, quads_to_triangles

#: The manipulators :func:`make_hand` builds.
KINDS = ("human", "witch", "alien", "tentacle")
#: The sides :func:`make_hand` builds: the modelled right hand and its mirror image.
SIDES = ("right", "left")
#: Suffix of a mirrored (left) hand's kind string (:func:`hand_from_kind`, a motion's ``source_kind``).
LEFT = "-left"
#: Catmull-Clark levels applied to the cages.
SUBDIVISIONS = 2
#: A ring of four cage vertices at half-size a subdivides to a near circle of radius about 0.93 a.
CAGE_SHRINK = 0.93


@dataclass(frozen=True)
class _Digit:
    name: str
    lengths: tuple[float, ...]
    radii: tuple[float, ...]
    limits: tuple[tuple[tuple[float, float], ...], ...]  # per bone: (x, y, z) limits in degrees
    curl: tuple[float, ...]  # rest flexion of each bone relative to its parent, degrees
    flatness: float = 0.88  # cross-section height / width
    knuckle: float = 1.08  # joint rings are this much thicker
    tip: float = 0.55  # size of the fingertip cap ring


_MCP = ((-25, 90), (-12, 12), (-22, 22))
_PIP = ((-5, 110), (-6, 6), (-6, 6))
_DIP = ((-12, 85), (-6, 6), (-6, 6))
_THUMB = (((-35, 60), (-35, 35), (-45, 45)), ((-15, 75), (-12, 12), (-15, 15)), ((-20, 90), (-6, 6), (-8, 8)))
_WRIST = ((-75, 80), (-15, 15), (-25, 35))
_THUMB_DIRECTIONS = ((-0.70, 0.65, -0.30), (-0.42, 0.85, -0.32), (-0.25, 0.93, -0.27))
#: The thumb's palm side faces the fingers: its flexion opposes it.
_THUMB_PALM_SIDE = (0.8, 0.1, -0.6)
_ROOT_ROTATION = 2 * np.pi


def _finger(name, lengths, radii, **kw) -> _Digit:
    return _Digit(name, lengths, radii, (_MCP, _PIP, _DIP), kw.pop("curl", (5.0, 10.0, 6.0)), **kw)


@dataclass(frozen=True)
class _HandSpec:
    fingers: tuple[_Digit, ...]  # along the knuckles, from the thumb side
    widths: tuple[float, ...]  # knuckle column width of each finger
    knuckles: tuple[float, ...]  # knuckle y of each finger
    spread: tuple[float, ...]  # rest spread of each finger, degrees (positive: towards +x)
    thumb: _Digit
    thumb_base: tuple[float, float, float]  # CMC joint relative to the palm's thumb-side wrist corner
    thumb_directions: tuple[tuple[float, float, float], ...]
    web: float
    palm_rows: tuple[float, ...]  # y of the palm rows between wrist and knuckles
    thickness: float  # palm thickness at the thumb side (the pinky side is 80 %)
    forearm: float


_HUMAN = _HandSpec(
    fingers=(
        _finger("index", (0.040, 0.024, 0.019), (0.0095, 0.0086, 0.0078)),
        _finger("middle", (0.044, 0.028, 0.020), (0.0098, 0.0089, 0.0080)),
        _finger("ring", (0.041, 0.027, 0.020), (0.0092, 0.0083, 0.0075)),
        _finger("pinky", (0.032, 0.020, 0.018), (0.0082, 0.0074, 0.0068)),
    ),
    widths=(0.0200, 0.0205, 0.0190, 0.0170),
    knuckles=(0.092, 0.096, 0.091, 0.082),
    spread=(-4.0, 0.0, 4.0, 9.0),
    thumb=_Digit("thumb", (0.046, 0.032, 0.027), (0.0135, 0.0105, 0.0095), _THUMB, (0.0, 8.0, 8.0), tip=0.6),
    thumb_base=(0.014, 0.020, -0.008),
    thumb_directions=_THUMB_DIRECTIONS,
    web=0.0025,
    palm_rows=(0.030, 0.062),
    thickness=0.042,
    forearm=0.07,
)

_WITCH = _HandSpec(
    fingers=tuple(
        _finger(
            f.name,
            tuple(1.5 * x for x in f.lengths),
            tuple(0.78 * r for r in f.radii),
            knuckle=1.22,
            tip=0.35,
            curl=(8.0, 14.0, 10.0),
        )
        for f in _HUMAN.fingers
    ),
    widths=tuple(0.85 * w for w in _HUMAN.widths),
    knuckles=tuple(1.1 * k for k in _HUMAN.knuckles),
    spread=(-6.0, 0.0, 6.0, 12.0),
    thumb=_Digit(
        "thumb",
        (0.052, 0.044, 0.038),
        (0.0115, 0.0085, 0.0075),
        _THUMB,
        (0.0, 10.0, 10.0),
        knuckle=1.2,
        tip=0.35,
    ),
    thumb_base=(0.012, 0.010, -0.006),
    thumb_directions=_THUMB_DIRECTIONS,
    web=0.004,
    palm_rows=(0.033, 0.068),
    thickness=0.036,
    forearm=0.07,
)

_ALIEN_LIMITS = ((-25, 95), (-12, 12), (-25, 25))
_ALIEN = _HandSpec(
    fingers=tuple(
        _Digit(
            name,
            (0.038, 0.030, 0.026, 0.022),
            (0.0155, 0.0145, 0.0135, 0.0125),
            (_ALIEN_LIMITS,) * 4,
            (4.0, 8.0, 8.0, 6.0),
            flatness=0.95,
            knuckle=1.05,
            tip=0.7,
        )
        for name in ("index", "middle")
    ),
    widths=(0.034, 0.034),
    knuckles=(0.095, 0.092),
    spread=(-5.0, 5.0),
    thumb=_Digit(
        "thumb",
        (0.048, 0.036, 0.030),
        (0.0175, 0.0150, 0.0140),
        _THUMB,
        (0.0, 8.0, 8.0),
        flatness=0.95,
        tip=0.7,
    ),
    thumb_base=(0.016, 0.012, -0.006),
    thumb_directions=_THUMB_DIRECTIONS,
    web=0.005,
    palm_rows=(0.031, 0.064),
    thickness=0.048,
    forearm=0.07,
)


class Hand(SkinnedMesh):
    """A procedural manipulator: a :class:`~solver.rig.skinning.SkinnedMesh` that knows its anatomy.

    Attributes
    ----------
    kind : str
        One of :data:`KINDS`.
    length : float
        Wrist to farthest fingertip at rest (the tentacle: base to tip), the scale for tolerances.
    chains : dict[str, tuple[int, ...]]
        Bone indices of each finger (or of the tentacle), proximal first.
    """

    def __init__(self, mesh: TriMesh, rig: Rig, weights, kind: str, length: float, chains):
        super().__init__(mesh, rig, weights)
        self.kind = kind
        self.length = float(length)
        self.chains: dict[str, tuple[int, ...]] = dict(chains)

    def flexion_dofs(self, chain: str) -> np.ndarray:
        """(c,) DOF indices that curl a chain of c bones into the palm (each bone's x rotation), proximal
        first."""
        if chain not in self.chains:
            raise SolverError(f"the {self.kind} hand has no chain {chain!r}; it has {', '.join(self.chains)}")
        return np.array([self.rig.rotation_dof(b, 0) for b in self.chains[chain]])

    def palmar_faces(self, bone: int, min_alignment: float = 0.5) -> np.ndarray:
        """(f,) the faces skinned mostly to ``bone`` whose rest normal points to its palm side (its z axis,
        the normal's component along it above ``min_alignment``), in increasing order."""
        W = self.weights.toarray()
        face_weight = W[self.mesh.faces].sum(1)  # (m, b)
        mine = np.argmax(face_weight, axis=1) == bone
        z = self.rig.matrix_local[bone, :3, 2]
        return np.flatnonzero(mine & (self.mesh.face_normals @ z > min_alignment))

    def contact_patches(self, points_per_patch: int = 40, seed: int = 0) -> dict[str, SurfacePoints]:
        """Palm-side contact patches, one per bone (finger pads, palm), as seeded random points.

        Points are drawn area-uniformly on :meth:`palmar_faces`; bones without such faces (the
        forearm) get none.
        """
        rng = np.random.default_rng(seed)
        patches = {}
        for b, name in enumerate(self.rig.names):
            faces = self.palmar_faces(b)
            if faces.size == 0 or (self.kind != "tentacle" and b == 0):
                continue
            area = self.mesh.face_areas[faces]
            pick = rng.choice(faces, size=points_per_patch, p=area / area.sum())
            patches[name] = SurfacePoints(pick, rng.dirichlet([1.0, 1.0, 1.0], points_per_patch))
        return patches


# ------------------------------------------------------------------------------------------- builders


class _Builder:
    """Bones and cage of a manipulator under construction."""

    def __init__(self, n_bones: int):
        self.cage = Cage(n_bones)
        self.n_bones = n_bones
        self.names: list[str] = []
        self.parents: list[int] = []
        self.heads: list[np.ndarray] = []
        self.tails: list[np.ndarray] = []
        self.zs: list[np.ndarray] = []
        self.limits: list[tuple] = []

    def weights(self, spec: dict[int, float]) -> np.ndarray:
        w = np.zeros(self.n_bones)
        for b, x in spec.items():
            w[b] = x
        return w

    def bone(self, name, parent, head, tail, z, limits) -> int:
        self.names.append(name)
        self.parents.append(parent)
        self.heads.append(np.asarray(head, float))
        self.tails.append(np.asarray(tail, float))
        self.zs.append(np.asarray(z, float))
        self.limits.append(limits)
        return len(self.names) - 1

    def frame(self, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        y = self.tails[b] - self.heads[b]
        y /= np.linalg.norm(y)
        z = self.zs[b] - np.dot(self.zs[b], y) * y
        z /= np.linalg.norm(z)
        return np.cross(y, z), y, z

    def chain(self, digit: _Digit, parent: int, start, direction, z_hint, directions=None) -> list[int]:
        """Add a digit's bones: each one turned by its rest curl towards its palm side, or along
        ``directions`` when given."""
        y = np.asarray(direction, float) / np.linalg.norm(direction)
        z = np.asarray(z_hint, float) - np.dot(z_hint, y) * y
        z /= np.linalg.norm(z)
        head = np.asarray(start, float)
        bones = []
        for k, (length, curl) in enumerate(zip(digit.lengths, digit.curl, strict=True)):
            if directions is not None:
                y = np.asarray(directions[k], float) / np.linalg.norm(directions[k])
                z = z - np.dot(z, y) * y
                z /= np.linalg.norm(z)
            else:
                c, s = np.cos(np.radians(curl)), np.sin(np.radians(curl))
                y, z = c * y + s * z, c * z - s * y
            tail = head + length * y
            bones.append(self.bone(f"{digit.name}_{k + 1}", parent, head, tail, z, digit.limits[k]))
            parent, head = bones[-1], tail
        return bones

    def grow(self, face: int, digit: _Digit, bones: list[int]) -> None:
        """Extrude ``face`` along a digit's bones: a ring mid-bone and one at each joint, then the tip."""
        for k, b in enumerate(bones):
            x, y, z = self.frame(b)
            r = digit.radii[k] / CAGE_SHRINK
            head, length = self.heads[b], np.linalg.norm(self.tails[b] - self.heads[b])
            self.ring(face, head + 0.5 * length * y, x, z, r, digit.flatness, {b: 1.0})
            if k + 1 < len(bones):
                xn, _, zn = self.frame(bones[k + 1])
                r = digit.knuckle * 0.5 * (digit.radii[k] + digit.radii[k + 1]) / CAGE_SHRINK
                self.ring(face, self.tails[b], x + xn, z + zn, r, digit.flatness, {b: 0.5, bones[k + 1]: 0.5})
            else:
                self.ring(face, head + 0.86 * length * y, x, z, r, digit.flatness, {b: 1.0})
                self.ring(face, self.tails[b], x, z, digit.tip * r, digit.flatness, {b: 1.0})

    def ring(self, face, center, x, z, r, flatness, weights) -> None:
        """Extrude ``face`` to a ring of four corners around ``center`` in the (x, z) plane."""
        x = x / np.linalg.norm(x)
        z = z - np.dot(z, x) * x
        z /= np.linalg.norm(z)
        corners = [center + a * r * x + c * flatness * r * z for a, c in ((1, 1), (-1, 1), (-1, -1), (1, -1))]
        self.cage.extrude([face], corners, self.weights(weights))

    def finish(self, kind: str, scale: float, chains) -> Hand:
        """Subdivide the cage, rig the bones; the length runs from y = 0 (wrist or base) forward.

        The quads are split into triangles at scale 1, then scaled: nearly equal diagonals could otherwise
        break differently after scaling, and a hand at another size would get other triangles (another
        topology, refusing the contact and annotation files made for it at life size)."""
        points, quads, attributes = catmull_clark(
            self.cage.points, self.cage.faces, self.cage.attributes, SUBDIVISIONS
        )
        triangles = quads_to_triangles(points, quads)
        points = points * scale
        mesh = TriMesh(points, triangles)
        attributes[attributes < 1e-12] = 0.0
        weights = sparse.csr_matrix(attributes / attributes.sum(1, keepdims=True))
        nd = 6 + 3 * (len(self.names) - 1)
        lower, upper = np.empty(nd), np.empty(nd)
        lower[:3], upper[:3] = -np.inf, np.inf
        lower[3:6], upper[3:6] = -_ROOT_ROTATION, _ROOT_ROTATION
        for b in range(1, len(self.names)):
            lim = np.radians(np.array(self.limits[b], float))
            lower[3 + 3 * b : 6 + 3 * b], upper[3 + 3 * b : 6 + 3 * b] = lim[:, 0], lim[:, 1]
        rig = Rig.from_bones(
            self.names,
            self.parents,
            np.array(self.heads) * scale,
            np.array(self.tails) * scale,
            np.array(self.zs),
            lower=lower,
            upper=upper,
        )
        return Hand(mesh, rig, weights, kind, float(points[:, 1].max()), chains)


def _palm_hand(spec: _HandSpec, kind: str, scale: float) -> Hand:
    n_fingers = len(spec.fingers)
    n_bones = 2 + sum(len(f.lengths) for f in spec.fingers) + len(spec.thumb.lengths)
    build = _Builder(n_bones)
    palm_z = (0.0, 0.0, -1.0)
    forearm = build.bone("forearm", -1, (0, -spec.forearm, 0), (0, 0, 0), palm_z, None)
    hand = build.bone("hand", forearm, (0, 0, 0), (0, spec.knuckles[1 % n_fingers], 0), palm_z, _WRIST)

    first_bone = 2 + np.cumsum([0] + [len(f.lengths) for f in spec.fingers])
    # Palm lattice: columns alternate finger, web, finger, ...; rows wrist, palm rows, knuckles.
    widths = []
    for i, w in enumerate(spec.widths):
        widths += [w] if i == 0 else [spec.web, w]
    xs = np.concatenate([[0.0], np.cumsum(widths)])
    xs -= xs[-1] / 2
    nx = len(xs) - 1
    rows = [0.0, *spec.palm_rows]
    ny = len(rows)
    lattice = np.empty((nx + 1, ny + 1, 2), np.int64)
    for i in range(nx + 1):
        finger = min(i // 2, n_fingers - 1)
        side = i / nx  # 0 at the thumb side, 1 at the pinky side
        for j in range(ny + 1):
            x = xs[i]
            if i == 0 and j == 0:
                x -= 0.25 * spec.widths[0]  # the thenar bulge at the thumb's base
            y = rows[j] if j < ny else spec.knuckles[finger]
            half = 0.5 * spec.thickness * (1 - 0.2 * side) * (1.06 if j == 0 else 1.0)
            arch = 0.004 * (1 - (2 * side - 1) ** 2)
            if j == 0:
                w = build.weights({forearm: 0.5, hand: 0.5})
            elif j < ny:
                w = build.weights({hand: 1.0})
            else:
                w = build.weights({hand: 0.5, first_bone[finger]: 0.5})
            lattice[i, j, 0] = build.cage.add_vertices([x, y, -half - 0.3 * arch], w)[0]
            lattice[i, j, 1] = build.cage.add_vertices([x, y, half + arch], w)[0]
    cage = build.cage
    for i in range(nx):
        for j in range(ny):
            for k, sign in ((0, -1), (1, 1)):
                quad = (
                    lattice[i, j, k],
                    lattice[i + 1, j, k],
                    lattice[i + 1, j + 1, k],
                    lattice[i, j + 1, k],
                )
                cage.add_face(quad, (0, 0, sign))

    def side_quad(a, b, outward):  # the quad between lattice columns a and b (each (i, j)), both layers
        return cage.add_face((lattice[a][0], lattice[b][0], lattice[b][1], lattice[a][1]), outward)

    distal = [side_quad((i, ny), (i + 1, ny), (0, 1, 0)) for i in range(nx)]
    wrist = [side_quad((i, 0), (i + 1, 0), (0, -1, 0)) for i in range(nx)]
    sides = {
        i: [side_quad((i, j), (i, j + 1), (sign, 0, 0)) for j in range(ny)] for i, sign in ((0, -1), (nx, 1))
    }

    # Forearm stub: the wrist faces pushed back twice, narrowing a little.
    for y, sx, sz in ((-0.35 * spec.forearm, 0.86, 0.9), (-0.97 * spec.forearm, 0.8, 0.85)):
        cage.extrude(
            wrist, lambda P, y=y, sx=sx, sz=sz: P * [sx, 0, sz] + [0, y, 0], build.weights({forearm: 1})
        )

    chains = {}
    for f, digit in enumerate(spec.fingers):
        i = 2 * f
        knuckle = np.array([0.5 * (xs[i] + xs[i + 1]), spec.knuckles[f], 0.0])
        a = np.radians(spec.spread[f])
        bones = build.chain(digit, hand, knuckle, (np.sin(a), np.cos(a), 0.0), palm_z)
        build.grow(distal[i], digit, bones)
        chains[digit.name] = tuple(bones)
    # The thumb: its metacarpal starts inside the palm near the wrist, on the -x side.
    corner = np.array([xs[0], 0.0, 0.0])
    bones = build.chain(
        spec.thumb,
        hand,
        corner + spec.thumb_base,
        spec.thumb_directions[0],
        _THUMB_PALM_SIDE,
        spec.thumb_directions,
    )
    base = [v for v in cage.faces[sides[0][0]] if cage.points[v][1] > 0]
    cage.set_attributes(base, build.weights({hand: 0.5, bones[0]: 0.5}))  # the thumb base's distal edge
    build.grow(sides[0][0], spec.thumb, bones)
    chains["thumb"] = tuple(bones)
    return build.finish(kind, scale, chains)


def _tentacle(scale: float) -> Hand:
    n, total, base, tip = 14, 0.55, 0.034, 0.006
    build = _Builder(n)
    limits = ((-50, 50), (-25, 25), (-50, 50))
    lengths = total * np.linspace(1.25, 0.75, n) / np.linspace(1.25, 0.75, n).sum()

    def radius(y):
        return base + (tip - base) * (y / total) ** 0.9

    ys = np.concatenate([[0.0], np.cumsum(lengths)])
    for b in range(n):
        build.bone(
            f"segment_{b + 1}", b - 1, (0, ys[b], 0), (0, ys[b + 1], 0), (0, 0, -1), limits if b else None
        )
    cage = build.cage
    r0 = radius(0.0) / CAGE_SHRINK
    corners = [(a * r0, 0.0, c * 0.9 * r0) for a, c in ((1, 1), (-1, 1), (-1, -1), (1, -1))]
    ring = cage.add_vertices(corners, build.weights({0: 1.0}))
    cage.add_face(ring, (0, -1, 0))
    face = cage.add_face(ring, (0, 1, 0))
    x, z = np.array([1.0, 0, 0]), np.array([0, 0, -1.0])
    for b in range(n):
        mid = 0.5 * (ys[b] + ys[b + 1])
        build.ring(face, (0, mid, 0), x, z, radius(mid) / CAGE_SHRINK, 0.9, {b: 1.0})
        if b + 1 < n:
            build.ring(
                face, (0, ys[b + 1], 0), x, z, radius(ys[b + 1]) / CAGE_SHRINK, 0.9, {b: 0.5, b + 1: 0.5}
            )
    build.ring(face, (0, total, 0), x, z, 0.6 * radius(total) / CAGE_SHRINK, 0.9, {n - 1: 1.0})
    return build.finish("tentacle", scale, {"tentacle": tuple(range(n))})


def make_hand(kind: str = "human", scale: float = 1.0, *, side: str = "right") -> Hand:
    """A procedural, rigged and skinned manipulator.

    Parameters
    ----------
    kind : str
        ``"human"`` (five fingers with an opposable thumb, 54 DOF), ``"witch"`` (long, thin, knobbly
        fingers, 54 DOF), ``"alien"`` (a thumb and two thick four-jointed fingers, 42 DOF) or
        ``"tentacle"`` (a tapering chain of 14 segments, 45 DOF).
    scale : float
        Multiplies every length (scale 1 is in metres: the human hand is about 19 cm from wrist to
        middle fingertip).
    side : str
        ``"right"`` (as modelled) or ``"left"``: its mirror image through the armature's x = 0 plane
        (:func:`mirror_hand`; see the module docstring).

    Returns
    -------
    Hand
        Deterministic: equal arguments give identical arrays. The mesh is closed, manifold and of
        genus 0, with every vertex on some face.
    """
    if side not in SIDES:
        raise SolverError(f"unknown side {side!r}; choose one of {', '.join(SIDES)}")
    if kind not in KINDS:
        raise SolverError(f"unknown hand kind {kind!r}; choose one of {', '.join(KINDS)}")
    scale = float(scale)
    if not (np.isfinite(scale) and scale > 0):
        raise SolverError(f"scale must be a positive finite number, got {scale!r}")
    if kind == "tentacle":
        hand = _tentacle(scale)
    else:
        hand = _palm_hand({"human": _HUMAN, "witch": _WITCH, "alien": _ALIEN}[kind], kind, scale)
    return mirror_hand(hand) if side == "left" else hand


def hand_from_kind(kind: str, scale: float = 1.0) -> Hand:
    """The procedural hand a kind string names: ``"<kind>"`` the right hand, ``"<kind>-left"``
    (:data:`LEFT`) its mirror image, as a motion's ``source_kind`` and ``source_scale`` name its source
    rig (:func:`make_hand`'s ``kind`` and ``scale``)."""
    if kind.endswith(LEFT):
        return make_hand(kind[: -len(LEFT)], scale, side="left")
    return make_hand(kind, scale)


# ------------------------------------------------------------------------------------------- mirroring


def mirror_hand(hand: Hand) -> Hand:
    """The mirror image of a procedural hand through its armature's x = 0 plane (a left hand from a
    right one), as a rig of its own: see the module docstring for the conventions."""
    rig = hand.rig
    S = np.diag([-1.0, 1.0, 1.0, 1.0])
    M = S @ rig.matrix_local @ S
    lower, upper = rig.lower.copy(), rig.upper.copy()
    flip = _mirror_signs(rig) < 0
    lower[flip], upper[flip] = -rig.upper[flip], -rig.lower[flip]
    mirrored = Rig(rig.names, rig.parents, M, rig.lengths, lower, upper, rig.locked, rig.rotation_modes)
    mesh = TriMesh(hand.mesh.vertices * [-1.0, 1.0, 1.0], hand.mesh.faces[:, ::-1])
    return Hand(mesh, mirrored, hand.weights, hand.kind, hand.length, hand.chains)


def _mirror_signs(rig: Rig) -> np.ndarray:
    """(d,) +1 or -1 per DOF: the mirrored rig's DOF is the sign times the original's."""
    if any(mode != "XYZ" for mode in rig.rotation_modes):
        raise SolverError("mirroring needs XYZ Euler bones (the procedural hands have them)")
    signs = np.ones(rig.n_dofs)
    signs[0] = -1.0  # root location x
    signs[3:][np.tile([False, True, True], rig.n_bones)] = -1.0
    return signs


def mirror_theta(rig: Rig, theta) -> np.ndarray:
    """(..., d) the mirrored rig's DOFs that pose the mirror image of ``rig`` posed at θ (..., d) (an
    involution: applying it twice gives θ back)."""
    return np.asarray(theta, dtype=np.float64) * _mirror_signs(rig)
