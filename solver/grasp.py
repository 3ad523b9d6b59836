"""Flex-to-contact (Magnenat-Thalmann, Laperrière and Thalmann, 1988): curl until the skin meets the object.

The 1988 paper finds, by dichotomous search, the flexion angle of a joint at which a chosen hand vertex
reaches the object. Here a *curl* of a chain moves its flexion DOFs together from their start values
towards their upper limits: ``θ(s) = θ0 + s (upper - θ0)`` on those DOFs (or towards their lower limits,
for rigs whose fingers curl by negative angles), ``s`` in [0, 1] (for one DOF
this is the paper's flexion angle). The object is a signed distance (negative inside), exact for closed
meshes (:class:`solver.sdf.MeshSDF`).

The search first samples ``s`` uniformly to find the first sample at which the skin is inside the
object (so a thin object is not stepped over and the *first* contact is found, not a later one), then
bisects between the last outside and the first inside sample until the skin is within ``tolerance`` of
the surface. The returned pose is always the outside end of the bracket: no penetration.

:func:`grasp` curls every finger of a :class:`~solver.hands.Hand`, in one of two ways (:data:`CURLS`):

* ``"together"``: all of a finger's joints curl together; when a segment touches, the joints up to that
  segment stop and the segments beyond it keep curling until they touch too (or reach their limits).
  The fingertips close first, like a claw.
* ``"in turn"``: one joint at a time from the knuckle out, each as the 1988 paper flexes a single joint:
  the knuckle curls with the finger straight until the finger touches, then the first joint beyond the
  touching segment curls, and so on, until each segment rests on the object or its joint reaches its
  limit. Fingers wrap a mug or a handle this way instead of hooking it with their tips.

Every vertex the moving joints carry is tested (exact signed distances), so nothing curls into the
object. Fingers curl independently (they do not collide with each other). Whether a finger touches is
measured at the end, not assumed: its skin's closest signed distance to the object. The result is a
quick baseline grip and a good start pose for :class:`solver.ContactIK`.

:func:`placement` and :func:`in_palm` put an upright object (a mug) where a procedural hand can grasp
it: against the palm, where the fingers wrap it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from geodesics import SurfacePoints, TriMesh

from .errors import SolverError
from .hands import Hand
from .rig import SkinnedMesh
from .sdf import MeshSDF

#: Uniform samples of the curl before bisection.
SAMPLES = 24
#: Default contact tolerance, as a fraction of the hand's size.
RELATIVE_TOLERANCE = 5e-4
#: Bisection stops after this many halvings even if the tolerance is not met (grazing contacts).
MAX_HALVINGS = 40
#: How :func:`grasp` curls a finger's joints (see the module docstring).
CURLS = ("together", "in turn")
#: The gap :func:`placement` leaves between the open hand's skin and the object, as a fraction of the
#: hand's length (4 mm on the life-size human hand).
PALM_GAP = 0.02


@dataclass(frozen=True)
class FlexResult:
    """Outcome of :func:`flex_to_contact`.

    Attributes
    ----------
    theta : (d,) ndarray
        The pose at contact (or fully curled).
    curl : float
        The curl parameter s in [0, 1].
    distance : float
        Signed distance of the chosen point from the object at ``theta`` (in [0, tolerance] on contact).
    reached : bool
        Whether the point reached the object before the DOFs hit their limits.
    evaluations : int
        Signed-distance evaluations.
    """

    theta: np.ndarray
    curl: float
    distance: float
    reached: bool
    evaluations: int


@dataclass(frozen=True)
class GraspResult:
    """Outcome of :func:`grasp`.

    Attributes
    ----------
    theta : (d,) ndarray
        The grip.
    distance : dict[str, float]
        Per finger, the closest signed distance of its skin to the object at ``theta`` (negative: it
        was inside the object already at the start, which curling cannot undo).
    touching : dict[str, bool]
        Per finger, whether its skin rests on the object: ``0 <= distance <= tolerance``.
    seconds : float
    evaluations : int
        Signed-distance evaluations.
    """

    theta: np.ndarray
    distance: dict[str, float]
    touching: dict[str, bool]
    seconds: float
    evaluations: int


def _as_sdf(target):
    """A signed-distance function ``f(points, max_distance)`` (exact at least within max_distance)."""
    if isinstance(target, TriMesh):
        return MeshSDF(target)
    if isinstance(target, MeshSDF):
        return target
    if callable(target):
        return lambda points, _max_distance=np.inf: target(points)
    raise SolverError(
        f"the object must be a closed TriMesh or a signed-distance callable, got {type(target).__name__}"
    )


def _curl_search(distance_at, n_samples: int, tolerance: float) -> tuple[float, float, bool, int]:
    """Smallest s in [0, 1] with distance_at(s) <= 0 approached from outside: (s, distance, reached,
    evaluations). ``distance_at`` maps an array of s to the minimum signed distances."""
    s = np.linspace(0.0, 1.0, n_samples + 1)
    d = distance_at(s)
    evaluations = s.size
    inside = np.flatnonzero(d <= 0)
    if inside.size == 0:
        return 1.0, float(d[-1]), False, evaluations
    first = int(inside[0])
    if first == 0:
        return 0.0, float(d[0]), True, evaluations
    lo, hi, d_lo = s[first - 1], s[first], float(d[first - 1])
    for _ in range(MAX_HALVINGS):
        if d_lo <= tolerance:
            break
        mid = 0.5 * (lo + hi)
        d_mid = float(distance_at(np.array([mid]))[0])
        evaluations += 1
        if d_mid <= 0:
            hi = mid
        else:
            lo, d_lo = mid, d_mid
    return float(lo), d_lo, True, evaluations


def _curled(theta: np.ndarray, dofs: np.ndarray, limit: np.ndarray, s: np.ndarray) -> np.ndarray:
    """(len(s), d) poses with ``dofs`` moved the fraction s from theta towards limit."""
    poses = np.repeat(theta[None], len(s), axis=0)
    poses[:, dofs] = theta[dofs] + s[:, None] * (limit[dofs] - theta[dofs])
    return poses


def _curl_limit(rig, direction: int) -> np.ndarray:
    """The limits a curl moves towards: upper for direction +1, lower for -1."""
    if direction not in (1, -1):
        raise SolverError(f"direction must be +1 (towards upper limits) or -1 (lower), got {direction!r}")
    return rig.upper if direction == 1 else rig.lower


def flex_to_contact(
    hand: SkinnedMesh,
    theta,
    dofs,
    point: SurfacePoints,
    target,
    tolerance: float | None = None,
    samples: int = SAMPLES,
    direction: int = 1,
) -> FlexResult:
    """Curl the given DOFs until a chosen skin point reaches the object's surface, without penetrating.

    Parameters
    ----------
    hand : SkinnedMesh
    theta : (d,) array_like
        Start pose.
    dofs : (c,) array_like of int
        The DOFs to flex together (e.g. ``hand.flexion_dofs("index")``, or a single joint's).
    point : SurfacePoints
        One point on ``hand.mesh``.
    target : TriMesh or callable
        The object: a closed mesh, or a signed-distance function of points (k, 3).
    tolerance : float, optional
        Contact tolerance (default ``RELATIVE_TOLERANCE * hand.size``).
    samples : int
        Uniform samples of the curl before bisection.
    direction : int
        +1 curls towards the DOFs' upper limits, -1 towards their lower limits.

    Returns
    -------
    FlexResult
    """
    rig = hand.rig
    limit = _curl_limit(rig, direction)
    t0 = rig.clip(theta)
    dofs = np.asarray(dofs, dtype=np.int64).reshape(-1)
    if dofs.size == 0 or np.any((dofs < 0) | (dofs >= rig.n_dofs)):
        raise SolverError(
            f"dofs must be a non-empty list of DOF indices in 0..{rig.n_dofs - 1}", dofs=dofs[dofs >= 0]
        )
    if not isinstance(point, SurfacePoints) or len(point) != 1:
        raise SolverError("point must be one geodesics.SurfacePoints point on the hand")
    sdf = _as_sdf(target)
    tol = RELATIVE_TOLERANCE * hand.size if tolerance is None else float(tolerance)
    skin = hand.point_skin([point])

    def distance_at(s):
        out = np.empty(len(s))
        for i, pose in enumerate(_curled(t0, dofs, limit, s)):
            p, _, _ = skin.sets[0].geometry(skin.vertices.positions(rig.kinematics(pose, derivatives=False)))
            out[i] = sdf(p, tol)[0]
        return out

    s, d, reached, evaluations = _curl_search(distance_at, samples, tol)
    return FlexResult(_curled(t0, dofs, limit, np.array([s]))[0], s, d, reached, evaluations)


def grasp(
    hand: Hand,
    target,
    theta0=None,
    chains=None,
    tolerance: float | None = None,
    samples: int = SAMPLES,
    direction: int = 1,
    curl: str = "together",
) -> GraspResult:
    """Curl every finger until its first contact with the object (then its outer segments on).

    Parameters
    ----------
    hand : Hand
        A procedural hand (its ``chains`` name the fingers).
    target : TriMesh or callable
        The object: a closed mesh, or a signed-distance function of points (k, 3).
    theta0 : (d,) array_like, optional
        Start pose, typically the hand placed near the object (default: rest).
    chains : sequence of str, optional
        Which fingers to curl (default: all).
    tolerance : float, optional
        Contact tolerance (default ``RELATIVE_TOLERANCE * hand.size``).
    samples : int
    direction : int
        +1 curls each bone's x rotation towards its upper limit (the procedural hands), -1 towards its
        lower limit.
    curl : str
        ``"together"`` or ``"in turn"`` (:data:`CURLS`, see the module docstring).

    Returns
    -------
    GraspResult
        ``touching[name]`` tells whether each finger ended on the object, measured.
    """
    if not isinstance(hand, Hand):
        raise SolverError("grasp needs a solver.hands.Hand (it curls the hand's finger chains)")
    if curl not in CURLS:
        raise SolverError(f"curl must be one of {', '.join(map(repr, CURLS))}, got {curl!r}")
    start = time.perf_counter()
    rig = hand.rig
    limit = _curl_limit(rig, direction)
    theta = rig.rest if theta0 is None else rig.clip(theta0)
    sdf = _as_sdf(target)
    tol = RELATIVE_TOLERANCE * hand.size if tolerance is None else float(tolerance)
    names = list(hand.chains) if chains is None else list(chains)
    owner = rig.deform_owner[np.asarray(hand.weights.argmax(axis=1)).ravel()]  # each vertex's posed bone
    unknown = [name for name in names if name not in hand.chains]
    if unknown:
        fingers = ", ".join(hand.chains)
        raise SolverError(f"the {hand.kind} hand has no finger {unknown[0]!r}; it has {fingers}")
    evaluations = 0
    for name in names:
        bones = list(hand.chains[name])
        while bones:
            moving = bones[:1] if curl == "in turn" else bones
            dofs = np.array([rig.rotation_dof(b, 0) for b in moving])
            vertices = np.flatnonzero(np.isin(owner, bones))  # the skin the moving joints carry
            skin = hand.vertex_skin(vertices)

            def distance_at(s, dofs=dofs, skin=skin, theta=theta):
                poses = _curled(theta, dofs, limit, s)
                X = np.concatenate([skin.positions(rig.kinematics(p, derivatives=False)) for p in poses])
                return sdf(X, tol).reshape(len(s), -1).min(1)

            s, _, reached, count = _curl_search(distance_at, samples, tol)
            evaluations += count
            theta = _curled(theta, dofs, limit, np.array([s]))[0]
            if not reached:
                if curl == "in turn":  # this joint at its limit: the next one goes on
                    bones = bones[1:]
                    continue
                break
            # The segment that touches: stop the joints up to it, keep curling the ones beyond. Curling
            # together, a finger inside the object at the start (s = 0) stays as it is.
            d = sdf(skin.positions(rig.kinematics(theta, derivatives=False)), tol)
            contact = owner[vertices[int(np.argmin(d))]]
            bones = bones[bones.index(contact) + 1 :] if s > 0 or curl == "in turn" else []
    X = hand.posed_vertices(theta)
    distance = {}
    for name in names:
        distance[name] = float(np.min(sdf(X[np.isin(owner, hand.chains[name])], np.inf)))
    touching = {name: bool(0.0 <= d <= tol) for name, d in distance.items()}
    return GraspResult(theta, distance, touching, time.perf_counter() - start, evaluations)


def palm_centre(hand: Hand) -> np.ndarray:
    """(3,) the centre of the palm's skin (rest pose, the hand's own space)."""
    palm = hand.palmar_faces(hand.rig.bone_index("hand"))
    return hand.mesh.vertices[np.unique(hand.mesh.faces[palm])].mean(axis=0)


def placement(hand: Hand, obj: TriMesh, gap: float | None = None) -> np.ndarray:
    """(4, 4) the hand's space to the object's, for grasping an upright, closed object from its side.

    The object stands on z = 0 around the z axis, as :func:`solver.objects.mug` does (its handle on
    +x). The hand, at rest, points its fingers along -y around the object and its thumb up; its palm
    faces the object from -x, the palm's centre at half the object's height, moved in until its skin is
    ``gap`` (default :data:`PALM_GAP` of the hand's length) from the object.
    """
    gap = PALM_GAP * hand.length if gap is None else float(gap)
    sdf = MeshSDF(obj)
    rotation = np.array([[0.0, 0.0, -1.0], [0.0, -1.0, 0.0], [-1.0, 0.0, 0.0]])  # x->-z, y->-y, z->-x
    skin = hand.posed_vertices(hand.rig.rest) @ rotation.T
    V = obj.vertices
    side = np.array([V[:, 0].min(), 0.0, 0.5 * (V[:, 2].min() + V[:, 2].max())])
    centre = side - rotation @ palm_centre(hand)  # the palm's centre on the object's side

    def clearance(back: float) -> float:  # exact below the gap (all that is compared), a bound above
        return float(sdf(skin + centre - [back, 0.0, 0.0], max(gap, 0.0)).min())

    near, far = 0.0, hand.length  # the skin's clearance grows as the hand backs away along -x
    while clearance(near) > gap:
        near, far = near - hand.length, near
    while far - near > 1e-9 * hand.length:
        mid = 0.5 * (near + far)
        near, far = (mid, far) if clearance(mid) < gap else (near, mid)
    M = np.eye(4)
    M[:3, :3] = rotation
    M[:3, 3] = centre - [far, 0.0, 0.0]
    return M


def in_palm(hand: Hand, obj: TriMesh, gap: float | None = None) -> TriMesh:
    """The upright object moved into the hand's space by :func:`placement`, ready to be grasped there."""
    M = np.linalg.inv(placement(hand, obj, gap))
    return TriMesh(obj.vertices @ M[:3, :3].T + M[:3, 3], obj.faces)
