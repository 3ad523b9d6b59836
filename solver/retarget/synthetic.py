"""Synthetic hand-object manipulations with ground truth: the test material of the retargeting pipeline.

No capture dataset is at hand, so :func:`generate` makes one: the procedural human hand
(:func:`solver.hands.make_hand`) approaches an object standing on a table, closes its fingers on it,
lifts it, turns it in the air, lets one finger go and take hold again (a regrip, so the contact set
changes while the object is held), carries it to another spot, sets it down, lets go and withdraws.
It is what the retargeting paper's input is (§3.1: object and hand meshes, per-frame poses, per-frame
contacts), with the ground truth a capture cannot give: the source rig's DOF curves and exact contacts.

How a motion is made (deterministic for equal arguments; ``seed`` draws the variations):

* **The grasp.** Each object has a grasp placement in its own frame (:data:`GRASPS`): the direction
  the palm faces, the direction the fingers point and an aim point. The open hand is oriented so, and
  slid along the palm direction until its skin is :data:`PALM_GAP` from the object (exact signed
  distances, :class:`solver.MeshSDF`); if it would then touch the table it is raised first. The
  fingers and the thumb are then closed by flex-to-contact (:func:`solver.grasp`, Magnenat-Thalmann et
  al. 1988) against the object *and the table* (the union of their signed distances), so no finger
  ends inside either.
* **The path.** Keyframes of the hand's root and of its finger DOFs are joined by minimum-jerk
  segments (Flash and Hogan 1985: ``s(u) = 10u³ - 15u⁴ + 6u⁵``, zero velocity and acceleration at both
  ends), so every DOF curve is C² and the hand comes to rest at each key, as reaching hands do. Root
  rotations are interpolated geodesically (slerp) about a pivot: the palm centre while the hand moves
  alone, the object's centre while it carries the object. Finger DOFs are interpolated linearly
  between the open pose and the grasp found by flex-to-contact.
* **The object** stands still on the table until lifted, then follows the hand rigidly (its pose is
  the root's forward kinematics times the grasp's fixed object-in-hand transform), and stands still
  where it was set down (upright, on the table) after release.
* **Ground truth.** ``source_theta`` holds the rig's DOFs per frame (root location and Euler angles,
  then 3 per bone: :class:`solver.Rig`); ``hand_vertices[f]`` is exactly
  ``hand.posed_vertices(source_theta[f])``. Contacts are dense samples of the hand's surface
  (area-uniform, ``density`` per cm², drawn once) that lie within ``contact_tolerance`` of the object
  in that frame; each is paired with its exact closest point on the object (``hand_contacts`` row i
  with ``object_contacts`` row i), so paired points are at most ``contact_tolerance`` apart in world
  space.
* **Checks.** Generation fails (:class:`~solver.SolverError`) if any hand vertex or contact sample
  ends more than :data:`PENETRATION_TOLERANCE` inside the object or the table, or the object inside
  the table (:func:`penetration` measures all three).

**Scale.** ``scale`` scales the whole scene alike (hand, object, table, path): a motion at scale s is
the scale-1 motion with every length multiplied by s.

**Bimanual** (:func:`bimanual`): the right hand grasps one half of the object (its fingers curl
against the object, the table and the object's symmetry plane, :data:`BIMANUAL_GRASPS`), and a
left hand mirrors it through that plane in the object's frame at every frame. The left hand is the
right rig reflected through its armature's x = 0 plane, a rig with DOFs of its own
(:func:`solver.hands.mirror_hand` and :func:`solver.hands.mirror_theta`, whose conventions
:mod:`solver.hands` states). The left motion's ``source_kind`` is ``"human-left"``;
:func:`solver.hands.hand_from_kind` rebuilds either rig from a motion's ``source_kind`` and
``source_scale``.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from geodesics import SurfacePoints, TriMesh

from .. import objects as procedural
from ..errors import SolverError
from ..grasp import grasp
from ..hands import LEFT, Hand, make_hand, mirror_hand, mirror_theta
from ..hands import hand_from_kind as source_hand  # the name this module's callers know it by
from ..rig import Rig
from ..rotations import axis_angle_to_matrix, matrix_to_axis_angle, matrix_to_euler
from ..sdf import Box, MeshSDF
from .motion import Contacts, Motion

__all__ = [
    "BIMANUAL_GRASPS",
    "GRASPS",
    "OBJECTS",
    "PHASES",
    "bimanual",
    "generate",
    "mirror_hand",
    "mirror_theta",
    "penetration",
    "source_hand",
]

#: Objects :func:`generate` and :func:`bimanual` support (:mod:`solver.objects`).
OBJECTS = ("mug", "cylinder", "box", "sphere")
#: The phases of a motion and their share of its frames.
PHASES = (
    ("approach", 0.12),
    ("reach", 0.08),
    ("close", 0.08),
    ("lift", 0.09),
    ("turn", 0.12),
    ("let go", 0.05),
    ("take hold", 0.05),
    ("carry", 0.12),
    ("place", 0.08),
    ("open", 0.07),
    ("withdraw", 0.14),
)
#: Contact tolerance by default: hand samples this close to the object are in contact (metres at scale 1).
CONTACT_TOLERANCE = 0.002
#: Hand surface samples per cm² by default (the human hand has about 600 cm² of skin).
DENSITY = 10.0
#: The open hand is slid towards the object until its skin is this far from it (metres at scale 1).
PALM_GAP = 0.0005
#: Hand and object may not sink deeper than this into each other or into the table (metres at scale 1).
PENETRATION_TOLERANCE = 0.0005
#: The object is aimed at the palm this far from the wrist towards the knuckles (0 to 1), where the
#: fingers can wrap it.
GRIP_REACH = 0.75
#: Hand points are checked for penetration within this distance of the object's surface (scale 1).
PENETRATION_BAND = 0.005
#: Height of the lift (metres at scale 1).
LIFT = 0.16
#: The table: full extents and where its top centre is relative to the object's start (scale 1).
TABLE_SIZE = (1.0, 0.8, 0.04)
TABLE_CENTER = (0.1, 0.1)


@dataclass(frozen=True)
class Grasp:
    """Where the hand takes an object, in the object's frame (metres at scale 1).

    Attributes
    ----------
    palm : (3,)
        The direction the palm faces (into the object).
    fingers : (3,)
        The direction the open fingers point, perpendicular to ``palm``.
    aim : (3,)
        The palm centre slides towards the object along ``palm`` on the line through this point.
    plane : (3,) or None
        For a bimanual grasp: the normal of the object's symmetry plane through ``aim``'s origin; the
        right hand stays on its positive side, the left hand is its mirror image.
    """

    palm: tuple[float, float, float]
    fingers: tuple[float, float, float]
    aim: tuple[float, float, float]
    plane: tuple[float, float, float] | None = None


#: Fingers of the side grasps tilted this far below the horizontal: with the thumb straight up the
#: root's Euler pitch sits at π/2 (gimbal lock), where its other two angles jump between frames.
_TILT = np.radians(30.0)
_ACROSS, _DOWN = float(np.cos(_TILT)), float(-np.sin(_TILT))
#: One-hand grasps (thumb up and tilted for the side grasps; over the top for the sphere).
GRASPS = {
    "mug": Grasp(palm=(0, -1, 0), fingers=(-_ACROSS, 0, _DOWN), aim=(0, 0, 0.062)),
    "cylinder": Grasp(palm=(1, 0, 0), fingers=(0, -_ACROSS, _DOWN), aim=(0, 0, 0.0)),
    "box": Grasp(palm=(1, 0, 0), fingers=(0, -_ACROSS, _DOWN), aim=(0, 0, 0.0)),
    "sphere": Grasp(palm=(0, 0, -1), fingers=(0, 1, 0), aim=(0, 0, 0)),
}
#: Two-hand grasps: the right hand's, the left hand mirrors it through ``plane``.
BIMANUAL_GRASPS = {
    "mug": Grasp(palm=(0, -1, 0), fingers=(-_ACROSS, 0, _DOWN), aim=(0, 0, 0.062), plane=(0, 1, 0)),
    "cylinder": Grasp(palm=(-1, 0, 0), fingers=(0, _ACROSS, _DOWN), aim=(0, 0, 0.015), plane=(1, 0, 0)),
    "box": Grasp(palm=(-1, 0, 0), fingers=(0, _ACROSS, _DOWN), aim=(0, 0, 0.015), plane=(1, 0, 0)),
    "sphere": Grasp(palm=(-1, 0, 0), fingers=(0, _ACROSS, _DOWN), aim=(0, 0, 0.012), plane=(1, 0, 0)),
}

Progress = Callable[[str, int, int], None]


# ------------------------------------------------------------------------------------------- rigid math


def _rigid(R: np.ndarray, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def _inverse(T: np.ndarray) -> np.ndarray:
    R, t = T[..., :3, :3], T[..., :3, 3]
    out = np.zeros_like(T)
    out[..., :3, :3] = np.swapaxes(R, -1, -2)
    out[..., :3, 3] = -np.einsum("...ji,...j->...i", R, t)
    out[..., 3, 3] = 1.0
    return out


def _apply(T: np.ndarray, X: np.ndarray) -> np.ndarray:
    return X @ T[:3, :3].T + T[:3, 3]


def minimum_jerk(u) -> np.ndarray:
    """(...) Flash and Hogan's minimum-jerk profile ``10u³ - 15u⁴ + 6u⁵`` of u (...) clipped to [0, 1]
    (C², at rest at both ends)."""
    u = np.clip(np.asarray(u, dtype=np.float64), 0.0, 1.0)
    return u**3 * (10.0 + u * (-15.0 + 6.0 * u))


def _interpolate(T0: np.ndarray, T1: np.ndarray, s: np.ndarray, pivot) -> np.ndarray:
    """(k, 4, 4) rigid transforms from T0 to T1: the image of ``pivot`` moves on a straight line, the
    rotation turns geodesically about it; s (k,) in [0, 1]."""
    R0, R1 = T0[:3, :3], T1[:3, :3]
    angle_axis = matrix_to_axis_angle(R0.T @ R1)
    aa = np.repeat(angle_axis[None], len(s), axis=0)
    aa[:, 0] *= s
    R = R0 @ axis_angle_to_matrix(aa)
    p0, p1 = _apply(T0, pivot), _apply(T1, pivot)
    centre = p0 + s[:, None] * (p1 - p0)
    out = np.zeros((len(s), 4, 4))
    out[:, :3, :3] = R
    out[:, :3, 3] = centre - R @ pivot
    out[:, 3, 3] = 1.0
    return out


# ------------------------------------------------------------------------------------------- hands


def _open_pose(hand: Hand) -> np.ndarray:
    """The open hand: fingers straightened at the knuckles, thumb swung away from the palm."""
    rig = hand.rig
    theta = rig.rest.copy()
    for name, bones in hand.chains.items():
        if name == "thumb":
            theta[rig.rotation_dof(bones[0], 0)] = np.radians(-30.0)
            theta[rig.rotation_dof(bones[1], 0)] = np.radians(-10.0)
        else:
            theta[rig.rotation_dof(bones[0], 0)] = np.radians(-12.0)
    return rig.clip(theta)


def _relaxed_pose(hand: Hand) -> np.ndarray:
    """The relaxed hand far from the object (fingers a little curled)."""
    rig = hand.rig
    theta = rig.rest.copy()
    for bones in hand.chains.values():
        for b in bones:
            theta[rig.rotation_dof(b, 0)] = np.radians(12.0)
    return rig.clip(theta)


class _Root:
    """World transforms of a hand's rest shape <-> its root DOFs (location, Euler angles)."""

    def __init__(self, rig: Rig):
        self.rig = rig
        self.M0 = rig.matrix_local[0]
        self.M0_inv = np.linalg.inv(self.M0)
        self.order = rig.rotation_modes[0]

    def theta(self, T: np.ndarray, compatible=None) -> np.ndarray:
        """(6,) root DOFs of the transform T (world from rest shape)."""
        B = self.M0_inv @ T @ self.M0
        euler = matrix_to_euler(B[:3, :3], self.order, compatible)
        return np.concatenate([B[:3, 3], euler])

    def transform(self, theta: np.ndarray) -> np.ndarray:
        """(4, 4) the world transform of the rest shape that the rig's root applies at θ (d,)."""
        return self.rig.pose_matrices(theta)[0] @ self.M0_inv


# ------------------------------------------------------------------------------------------- the scene


@dataclass(frozen=True)
class _Scene:
    hand: Hand
    mesh: TriMesh
    sdf: MeshSDF
    centre: np.ndarray  # object-frame centre of its bounding box
    start: np.ndarray  # (4, 4) the object's pose on the table
    table: Box
    table_pose: np.ndarray
    table_size: np.ndarray
    scale: float


def _object_mesh(name: str, scale: float) -> TriMesh:
    if name not in OBJECTS:
        raise SolverError(f"unknown object {name!r}; choose one of {', '.join(OBJECTS)}")
    mesh = getattr(procedural, name)()
    return TriMesh(mesh.vertices * scale, mesh.faces)


def _scene(hand: Hand, name: str, scale: float) -> _Scene:
    mesh = _object_mesh(name, scale)
    lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
    start = _rigid(np.eye(3), [0.0, 0.0, -lo[2]])  # standing on the table top z = 0
    size = np.array(TABLE_SIZE) * scale
    centre = np.array([TABLE_CENTER[0] * scale, TABLE_CENTER[1] * scale, -size[2] / 2])
    return _Scene(
        hand,
        mesh,
        MeshSDF(mesh),
        0.5 * (lo + hi),
        start,
        Box(centre, size / 2),
        _rigid(np.eye(3), centre),
        size,
        scale,
    )


def _palm_centre(hand: Hand, reach: float = 0.5) -> np.ndarray:
    """Rest-space centre of the palmar skin of the palm's band at ``reach`` (0 = wrist, 1 = the middle
    finger's knuckle) along the hand, area-weighted."""
    rig = hand.rig
    faces = hand.palmar_faces(rig.bone_index("hand"))
    knuckle = rig.heads[hand.chains["middle"][0]] if "middle" in hand.chains else rig.tails[1]
    centroids = hand.mesh.vertices[hand.mesh.faces[faces]].mean(1)
    y = centroids[:, 1] / knuckle[1]
    band = np.abs(y - reach) < 0.15
    area = hand.mesh.face_areas[faces[band]]
    return (centroids[band] * area[:, None]).sum(0) / area.sum()


def _place_hand(scene: _Scene, spec: Grasp, theta_open: np.ndarray, root: _Root) -> np.ndarray:
    """The world transform of the open hand at the grasp: oriented by ``spec``, slid along the palm
    direction until its skin is PALM_GAP from the object, raised first if it would touch the table."""
    hand, s = scene.hand, scene.scale
    R_obj = scene.start[:3, :3]
    a = R_obj @ np.asarray(spec.palm, float)
    f = R_obj @ np.asarray(spec.fingers, float)
    a, f = a / np.linalg.norm(a), f / np.linalg.norm(f)
    f = f - np.dot(f, a) * a
    f /= np.linalg.norm(f)
    z = -a
    R = np.stack([np.cross(f, z), f, z], 1)
    palm = _palm_centre(hand, GRIP_REACH)
    shape = hand.posed_vertices(theta_open)  # the open hand at the rest root
    aim = _apply(scene.start, np.asarray(spec.aim, float) * s)
    gap = PALM_GAP * s
    lift = np.zeros(3)

    def transform(back: float) -> np.ndarray:
        return _rigid(R, aim + lift - back * a - R @ palm)

    def clearance(back: float) -> float:
        X = _apply(_inverse(scene.start) @ transform(back), shape)
        return float(scene.sdf(X, 0.01 * s).min())

    reach = 0.3 * s
    for _ in range(4):
        samples = np.linspace(reach, 0.0, 61)
        d = np.array([clearance(b) for b in samples])
        inside = np.flatnonzero(d <= gap)
        if inside.size == 0 or inside[0] == 0:
            raise SolverError("cannot place the hand against the object (check the grasp placement)")
        lo, hi = samples[inside[0] - 1], samples[inside[0]]  # clearance(lo) > gap >= clearance(hi)
        for _ in range(50):
            mid = 0.5 * (lo + hi)
            if clearance(mid) > gap:
                lo = mid
            else:
                hi = mid
        T = transform(lo)
        low = scene.table.evaluate(_apply(T, shape))[0].min()
        if low >= 2 * gap:
            return T
        lift = lift + np.array([0.0, 0.0, 2 * gap - low + 1e-3 * s])
    raise SolverError("cannot place the hand against the object without touching the table")


def _grasp(scene: _Scene, spec: Grasp, root: _Root) -> tuple[np.ndarray, np.ndarray]:
    """(T_grasp, θ_grasp): the placed hand with its fingers closed by flex-to-contact."""
    hand = scene.hand
    theta_open = _open_pose(hand)
    T = _place_hand(scene, spec, theta_open, root)
    theta0 = theta_open.copy()
    theta0[:6] = root.theta(T)
    to_object = _inverse(scene.start)
    plane = None
    if spec.plane is not None:
        n = scene.start[:3, :3] @ np.asarray(spec.plane, float)
        plane = (n / np.linalg.norm(n), _apply(scene.start, scene.centre))

    def obstacles(X):
        d = np.minimum(scene.sdf(_apply(to_object, X), 0.01 * scene.scale), scene.table.evaluate(X)[0])
        if plane is not None:  # the other hand's half of space
            d = np.minimum(d, (X - plane[1]) @ plane[0] - PALM_GAP * scene.scale)
        return d

    theta = grasp(hand, obstacles, theta0, curl="in turn").theta  # fingers wrap the object
    return root.transform(theta), theta


# ------------------------------------------------------------------------------------------- the path


def _keyframes(scene: _Scene, T_grasp, theta_grasp, rng: np.random.Generator, root: _Root):
    """The key poses: (root transform, finger pose, object pose or None = carried) per phase end."""
    hand, s = scene.hand, scene.scale
    palm = _palm_centre(hand)
    open_, relaxed = _open_pose(hand), _relaxed_pose(hand)
    up = np.array([0.0, 0.0, 1.0])
    a = -T_grasp[:3, 2]  # palm direction at the grasp
    back = a - np.dot(a, up) * up
    back = -back / max(np.linalg.norm(back), 1e-12) if np.linalg.norm(back) > 1e-6 else -T_grasp[:3, 1]

    def shifted(T, offset):
        out = T.copy()
        out[:3, 3] += offset
        return out

    def turned(T, axis, degrees, pivot_world):
        Rz = axis_angle_to_matrix(np.concatenate([[np.radians(degrees)], axis]))
        out = T.copy()
        out[:3, :3] = Rz @ T[:3, :3]
        out[:3, 3] = pivot_world + Rz @ (T[:3, 3] - pivot_world)
        return out

    # Approach: from well back and above, turned a little about the palm centre.
    T_pre = shifted(T_grasp, s * (0.07 * (-a) + 0.03 * up))
    axis = rng.normal(size=3)
    T_start = turned(
        shifted(T_pre, s * (0.15 * back + 0.08 * up)),
        axis / np.linalg.norm(axis),
        rng.uniform(10.0, 25.0),
        _apply(shifted(T_pre, s * (0.15 * back + 0.08 * up)), palm),
    )
    O0 = scene.start
    centre0 = _apply(O0, scene.centre)
    O_lift = shifted(O0, s * LIFT * up)
    heading = rng.uniform(0, 2 * np.pi)
    tilt_axis = np.array([np.cos(heading), np.sin(heading), 0.0])
    O_turn = turned(O_lift, tilt_axis, rng.uniform(45.0, 70.0), centre0 + s * LIFT * up)
    O_turn = turned(O_turn, up, rng.uniform(-40.0, 40.0), centre0 + s * LIFT * up)
    distance, direction = rng.uniform(0.12, 0.2) * s, rng.uniform(0, 2 * np.pi)
    move = distance * np.array([np.cos(direction), np.sin(direction), 0.0])
    O_place = turned(shifted(O0, move), up, rng.uniform(-45.0, 45.0), centre0 + move)
    O_carry = shifted(O_place, s * LIFT * up)
    # Let go with one finger (not the thumb): it swings most of the way open, then takes hold again.
    fingers = [c for c in hand.chains if c != "thumb"]
    finger = fingers[int(rng.integers(len(fingers)))]
    dofs = np.concatenate([hand.rig.bone_dofs(b) for b in hand.chains[finger]])
    loose = theta_grasp.copy()
    loose[dofs] = theta_grasp[dofs] + 0.8 * (open_[dofs] - theta_grasp[dofs])
    C = _inverse(T_grasp) @ O0  # the object in the hand's frame while held

    def held(O):
        return O @ _inverse(C)

    T_place = held(O_place)
    a_end = -T_place[:3, 2]
    back_end = a_end - np.dot(a_end, up) * up
    back_end = -back_end / np.linalg.norm(back_end) if np.linalg.norm(back_end) > 1e-6 else back
    T_end = shifted(T_place, s * (0.12 * back_end + 0.07 * up))
    keys = [
        (T_start, relaxed, None),
        (T_pre, open_, None),  # approach
        (T_grasp, open_, None),  # reach
        (T_grasp, theta_grasp, O0),  # close
        (held(O_lift), theta_grasp, O_lift),  # lift
        (held(O_turn), theta_grasp, O_turn),  # turn
        (held(O_turn), loose, O_turn),  # let go
        (held(O_turn), theta_grasp, O_turn),  # take hold
        (held(O_carry), theta_grasp, O_carry),  # carry
        (T_place, theta_grasp, O_place),  # place
        (T_place, open_, None),  # open
        (T_end, relaxed, None),  # withdraw
    ]
    return keys, C, finger


def _boundaries(frames: int, rng: np.random.Generator) -> np.ndarray:
    """Frame index of each key: phase shares jittered by up to ±15 %."""
    share = np.array([w for _, w in PHASES]) * rng.uniform(0.85, 1.15, len(PHASES))
    edges = np.concatenate([[0.0], np.cumsum(share / share.sum())])
    b = np.round(edges * (frames - 1)).astype(np.int64)
    if np.any(np.diff(b) < 1):
        raise SolverError(
            f"{frames} frames are too few for {len(PHASES)} phases; use at least {4 * len(PHASES)}"
        )
    return b


def _trajectory(scene, keys, C, bounds, root: _Root, pivot_object):
    """Per-frame θ (F, d) and object poses (F, 4, 4) along the keyframes."""
    hand = scene.hand
    F = int(bounds[-1]) + 1
    d = hand.rig.n_dofs
    theta = np.zeros((F, d))
    transforms = np.zeros((F, 4, 4))
    carried = np.zeros(F, bool)
    palm = _palm_centre(hand)
    for k in range(len(keys) - 1):
        (T0, q0, O0), (T1, q1, O1) = keys[k], keys[k + 1]
        first, last = bounds[k], bounds[k + 1]
        u = (np.arange(first, last + 1) - first) / (last - first)
        s = minimum_jerk(u)
        both_held = O0 is not None and O1 is not None
        if both_held:
            # The object moves (or rests in the hand): interpolate it about its centre, the hand follows.
            Os = _interpolate(O0, O1, s, pivot_object)
            Ts = Os @ _inverse(C)
        else:
            Ts = _interpolate(T0, T1, s, palm)
        theta[first : last + 1] = q0 + s[:, None] * (q1 - q0)
        transforms[first : last + 1] = Ts
        carried[first : last + 1] |= both_held
    compatible = None
    for f in range(F):
        theta[f, :6] = root.theta(transforms[f], compatible)
        compatible = theta[f, 3:6]
    return theta, carried


def _object_poses(scene, theta, carried, C, root: _Root) -> np.ndarray:
    """The object on the table until lifted, with the hand while carried, where it was left after."""
    F = len(theta)
    poses = np.repeat(scene.start[None], F, axis=0)
    held = np.flatnonzero(carried)
    for f in held:
        poses[f] = root.transform(theta[f]) @ C
    if held.size:
        poses[held[-1] + 1 :] = poses[held[-1]]
    # Re-orthonormalize (products of rigid transforms drift by rounding only).
    U, _, Vt = np.linalg.svd(poses[:, :3, :3])
    poses[:, :3, :3] = U @ Vt
    return poses


# ------------------------------------------------------------------------------------------- contacts


def _surface_samples(mesh: TriMesh, density: float, scale: float, seed: int) -> SurfacePoints:
    """Area-uniform random points on a mesh, ``density`` per cm² (of the scale-1 surface)."""
    rng = np.random.default_rng(seed)
    area = mesh.face_areas
    count = max(1, round(density * area.sum() / (scale * scale) * 1e4))
    faces = rng.choice(mesh.n_faces, size=count, p=area / area.sum())
    faces.sort()
    return SurfacePoints(faces, rng.dirichlet([1.0, 1.0, 1.0], count))


def _near(sdf: MeshSDF, Y: np.ndarray, band: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The points of Y (k, 3) within ``band`` of the surface (inside or outside): their indices (j,),
    signed distances (j,), closest points (j, 3) and faces (j,). Farther points cost a box test or one
    nearest-neighbour search (:meth:`solver.MeshSDF.query` with ``max_distance`` and ``band``)."""
    signed, closest, face = sdf.query(Y, band, band)
    near = np.flatnonzero(np.abs(signed) <= band)
    return near, signed[near], closest[near], face[near]


def _contacts(
    hand_mesh: TriMesh,
    samples: SurfacePoints,
    hand_vertices: np.ndarray,
    obj: TriMesh,
    sdf: MeshSDF,
    poses: np.ndarray,
    tolerance: float,
    band: float,
    progress: Progress | None,
) -> tuple[Contacts, Contacts, np.ndarray]:
    """Paired (object, hand) contacts of every frame, and per frame the deepest penetration of the hand
    (its samples and vertices within ``band`` of the object's surface) into the object."""
    corners = hand_mesh.faces[samples.faces]
    k = len(samples)
    hand_parts, object_faces, object_points, counts = [], [], [], []
    depth = np.zeros(len(poses))
    F = len(poses)
    for f in range(F):
        V = hand_vertices[f]
        P = np.concatenate([np.einsum("kc,kcd->kd", samples.bary, V[corners]), V])
        Y = (P - poses[f, :3, 3]) @ poses[f, :3, :3]
        near, d, closest, face = _near(sdf, Y, max(band, tolerance))
        depth[f] = max(0.0, -float(d.min())) if d.size else 0.0
        keep = (np.abs(d) <= tolerance) & (near < k)
        rows = near[keep]
        hand_parts.append(rows)
        object_faces.append(face[keep])
        object_points.append(closest[keep])
        counts.append(rows.size)
        if progress is not None and (f % 50 == 0 or f == F - 1):
            progress("contacts", f + 1, F)
    rows = np.concatenate(hand_parts)
    offsets = np.concatenate([[0], np.cumsum(counts)])
    on_object = SurfacePoints.from_positions(obj, np.concatenate(object_faces), np.concatenate(object_points))
    object_contacts = Contacts(offsets, on_object.faces, on_object.bary)
    hand_contacts = Contacts(offsets, samples.faces[rows], samples.bary[rows])
    return object_contacts, hand_contacts, depth


def penetration(motion: Motion, band: float | None = None) -> dict[str, np.ndarray]:
    """Per-frame penetration depths (F,) of a motion, in metres (0 where there is none).

    * ``"hand_object"`` — the deepest hand vertex inside the object, among those within ``band`` of
      its surface (default :data:`PENETRATION_BAND` times the source scale; a vertex deeper than that
      must have crossed the band in an earlier frame, unless it starts inside);
    * ``"hand_table"`` — the deepest hand vertex inside the table (zeros without a table);
    * ``"object_table"`` — the deepest object vertex inside the table.
    """
    band = PENETRATION_BAND * motion.source_scale if band is None else float(band)
    sdf = MeshSDF(motion.object_mesh)
    depth = np.zeros(motion.n_frames)
    for f, O in enumerate(motion.object_poses):
        Y = (motion.hand_vertices[f] - O[:3, 3]) @ O[:3, :3]
        _, d, _, _ = _near(sdf, Y, band)
        depth[f] = max(0.0, -float(d.min())) if d.size else 0.0
    return {"hand_object": depth, **_table_depths(motion)}


def _table_depths(motion: Motion) -> dict[str, np.ndarray]:
    F = motion.n_frames
    out = {k: np.zeros(F) for k in ("hand_table", "object_table")}
    if motion.table is None:
        return out
    table = Box(motion.table[:3, 3], motion.table_size / 2, motion.table[:3, :3])
    hand = table.evaluate(motion.hand_vertices.reshape(-1, 3))[0].reshape(F, -1).min(1)
    X = np.einsum("fij,vj->fvi", motion.object_poses[:, :3, :3], motion.object_mesh.vertices)
    X += motion.object_poses[:, None, :3, 3]
    obj = table.evaluate(X.reshape(-1, 3))[0].reshape(F, -1).min(1)
    out["hand_table"] = np.maximum(0.0, -hand)
    out["object_table"] = np.maximum(0.0, -obj)
    return out


# ------------------------------------------------------------------------------------------- API


def _check(frames, fps, scale, contact_tolerance, density) -> tuple[int, float]:
    """The frame count and the contact tolerance (default :data:`CONTACT_TOLERANCE` times ``scale``) of
    a motion's parameters, which are checked."""
    frames = int(frames)
    if frames < 4 * len(PHASES):
        raise SolverError(f"a motion needs at least {4 * len(PHASES)} frames, got {frames}")
    for name, value in (("fps", fps), ("scale", scale), ("density", density)):
        if not (np.isfinite(value) and value > 0):
            raise SolverError(f"{name} must be a positive finite number, got {value!r}")
    if contact_tolerance is not None and not (np.isfinite(contact_tolerance) and contact_tolerance > 0):
        raise SolverError(f"contact_tolerance must be a positive finite number, got {contact_tolerance!r}")
    return frames, CONTACT_TOLERANCE * scale if contact_tolerance is None else float(contact_tolerance)


@functools.lru_cache(maxsize=16)
def _cached_grasp(kind: str, object_name: str, spec: Grasp, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """The grasp of :func:`_grasp` for a procedural hand: it depends on neither the seed nor the frame
    count, and is most of the cost of a short motion, so motions of one object share it."""
    hand = make_hand(kind, scale)
    T, theta = _grasp(_scene(hand, object_name, scale), spec, _Root(hand.rig))
    T.setflags(write=False)
    theta.setflags(write=False)
    return T, theta


def _plan(hand, object_name, spec, frames, seed, scale, progress):
    root = _Root(hand.rig)
    scene = _scene(hand, object_name, scale)
    if progress is not None:
        progress("grasp", 0, 1)
    T_grasp, theta_grasp = _cached_grasp(hand.kind, object_name, spec, float(scale))
    if progress is not None:
        progress("grasp", 1, 1)
    rng = np.random.default_rng(seed)
    keys, C, _ = _keyframes(scene, T_grasp, theta_grasp, rng, root)
    bounds = _boundaries(frames, rng)
    theta, carried = _trajectory(scene, keys, C, bounds, root, scene.centre)
    poses = _object_poses(scene, theta, carried, C, root)
    return scene, theta, poses


def _pose_all(hand: Hand, theta: np.ndarray, progress: Progress | None) -> np.ndarray:
    F = len(theta)
    V = np.empty((F, hand.mesh.n_vertices, 3))
    for f in range(F):
        V[f] = hand.posed_vertices(theta[f])
        if progress is not None and (f % 100 == 0 or f == F - 1):
            progress("pose", f + 1, F)
    return V


def _motion(scene, hand, kind, theta, poses, fps, tolerance, density, seed, progress) -> Motion:
    s = scene.scale
    V = _pose_all(hand, theta, progress)
    samples = _surface_samples(hand.mesh, density, s, seed)
    object_contacts, hand_contacts, depth = _contacts(
        hand.mesh, samples, V, scene.mesh, scene.sdf, poses, tolerance, PENETRATION_BAND * s, progress
    )
    motion = Motion(
        fps=fps,
        object_mesh=scene.mesh,
        object_poses=poses,
        hand_mesh=hand.mesh,
        hand_vertices=V,
        object_contacts=object_contacts,
        hand_contacts=hand_contacts,
        table=scene.table_pose,
        table_size=scene.table_size,
        source_kind=kind,
        source_scale=s,
        source_theta=theta,
    )
    limit = PENETRATION_TOLERANCE * s
    depths = {"hand_object": depth, **_table_depths(motion)}
    for what, d in depths.items():
        if d.max() > limit:
            raise SolverError(
                f"the generated motion penetrates ({what.replace('_', ' into ')}: {d.max() * 1e3:.2f} mm at "
                f"frame {int(np.argmax(d))}, tolerance {limit * 1e3:.2f} mm)"
            )
    return motion


def generate(
    object_name: str = "mug",
    frames: int = 600,
    fps: float = 120.0,
    seed: int = 0,
    scale: float = 1.0,
    progress: Progress | None = None,
    contact_tolerance: float | None = None,
    density: float = DENSITY,
) -> Motion:
    """A synthetic manipulation of one object by the procedural right human hand, with ground truth.

    Parameters
    ----------
    object_name : str
        One of :data:`OBJECTS`.
    frames : int
        Frame count (at least ``4 * len(PHASES)``).
    fps : float
        Frame rate; the motion lasts ``(frames - 1) / fps`` seconds.
    seed : int
        Draws the approach direction, the turn, the released finger, where the object is set down and
        the phases' timing. Equal arguments give identical arrays.
    scale : float
        Scales the whole scene (hand, object, table and path).
    progress : callable, optional
        ``progress(stage, done, total)`` with stages ``"grasp"``, ``"pose"`` and ``"contacts"``.
    contact_tolerance : float, optional
        Hand samples within this distance of the object are contacts (default
        :data:`CONTACT_TOLERANCE` times ``scale``).
    density : float
        Hand surface samples per cm² of the scale-1 hand; contacts per frame grow in proportion.

    Returns
    -------
    Motion
        With ``source_kind = "human"``, ``source_theta``, paired contacts and the table.

    Raises
    ------
    SolverError
        For an unknown object or bad parameters, or if the generated motion would penetrate.
    """
    frames, tolerance = _check(frames, fps, scale, contact_tolerance, density)
    hand = make_hand("human", scale)
    _object_mesh(object_name, 1.0)
    scene, theta, poses = _plan(hand, object_name, GRASPS[object_name], frames, seed, scale, progress)
    return _motion(scene, hand, "human", theta, poses, fps, tolerance, density, seed, progress)


def bimanual(
    object_name: str = "box",
    frames: int = 600,
    fps: float = 120.0,
    seed: int = 0,
    scale: float = 1.0,
    progress: Progress | None = None,
    contact_tolerance: float | None = None,
    density: float = DENSITY,
) -> tuple[Motion, Motion]:
    """Both hands manipulating one object: (right, left) motions with the same object poses.

    The right hand's motion is made as in :func:`generate` but with the grasp of
    :data:`BIMANUAL_GRASPS` (its fingers stop at the object's symmetry plane); the left hand is its
    mirror image through that plane, in the object's frame, at every frame. The left motion's
    ``source_kind`` is ``"human-left"`` and its ``source_theta`` is in the DOFs of
    :func:`mirror_hand` (see the module docstring). Parameters as for :func:`generate`.
    """
    frames, tolerance = _check(frames, fps, scale, contact_tolerance, density)
    right = make_hand("human", scale)
    left = mirror_hand(right)
    _object_mesh(object_name, 1.0)
    spec = BIMANUAL_GRASPS[object_name]
    scene, theta, poses = _plan(right, object_name, spec, frames, seed, scale, progress)
    # The world reflection that maps the right hand onto the left at frame f: O_f P O_f^-1, with P the
    # reflection through the object's symmetry plane (object frame).
    n = np.asarray(spec.plane, float)
    n /= np.linalg.norm(n)
    P = np.eye(4)
    P[:3, :3] -= 2 * np.outer(n, n)
    P[:3, 3] = 2 * np.dot(scene.centre, n) * n
    S = np.diag([-1.0, 1.0, 1.0, 1.0])
    root_r, root_l = _Root(right.rig), _Root(left.rig)
    theta_left = mirror_theta(right.rig, theta)
    compatible = None
    for f in range(len(theta)):
        T_left = poses[f] @ P @ _inverse(poses[f]) @ root_r.transform(theta[f]) @ S
        theta_left[f, :6] = root_l.theta(T_left, compatible)
        compatible = theta_left[f, 3:6]
    right_motion = _motion(scene, right, "human", theta, poses, fps, tolerance, density, seed, progress)
    left_scene = _Scene(left, *(getattr(scene, k) for k in list(scene.__dataclass_fields__)[1:]))
    left_motion = _motion(
        left_scene, left, "human" + LEFT, theta_left, poses, fps, tolerance, density, seed, progress
    )
    return right_motion, left_motion
