"""Where a solve starts when the hand must travel: the grasp a layout of contacts implies.

Contact IK is a local method: from a hand far from its contacts (the wrist to move by a hand length and
turn by half a turn, the fingers to wrap an object) it ends in a minimum on the way, which is the paper's
own users' first complaint (Contact Edit §7: "solutions to difficult optimization problems such as those
which involved very large wrist movement"). Their answer was to move the object and solve again; this
module finds the start instead, in three steps repeated a few times, and a fourth:

1. **The root.** The rigid motion that best lays the hand's contact points onto their targets and their
   normals against the object's (each point with a second one a little along its normal, paired with
   its target a little inside along the object's normal: the rotation is then fixed by two patches, or
   even one), weighing every patch alike whatever its number of points (weighted Kabsch,
   :func:`geodesics.rigid.rigid_fit`), composed with the root's present motion.
2. **The fingers.** With the root held, a short solve of the other DOFs towards the targets, without the
   skin kept out of the object (the finger pads would otherwise catch on it on their way).
3. Again: the root fits the fingers as they now curl, and the fingers the root as it now stands.
4. Last, the whole hand, root and fingers, solved from the start kept without the solids, for at most
   :data:`UNSOLID_EVALUATIONS`, and kept instead if its energy is lower: the table's and the object's
   stiff walls make the trust region creep along the object's surface, hundreds of evaluations for a
   grasp it reaches in tens without them, and from that grasp the solids only push the skin out; but a
   grasp deep in the object (a patch out of reach pulling the skin in) is pushed out more slowly still.

It starts once from the fingers as given, once from the open hand (when they differ) and once from that hand
with its fingers curled (every joint but the root's that moves the pads along their normals, the wrist's too,
turned by :data:`CURL`): laid onto contacts around an object, flat pads make a chord through it, and a finger
solved from there without the solids threads the object's wall, where the local solve cannot get it out;
curled pads make an arc and the root fits outside. The starts go through the rounds side by side, and one
whose energy after a round is :data:`PRUNE` times the best's goes no further. It keeps the start with the
lowest energy, or the hand where it stands with only its fingers solved (step 2 alone, in rounds as well), if
that is lower still, and lower than every root fit: a hand may already stand where its grasp is, with only its
fingers to wrap (the Example's hand beside its mug), and a root fit of the open fingers' pads would lay it
through the object; but a hand that stands through the object itself is not at its grasp (a mug carried 3 cm
and turned 29° from the human hand at rest: its wall through the palm, and the solve crept for 2,000
evaluations from there, 12 s, to a pose 7 mm off; a root fit of the open hand lay better); step 4 follows
a root fit, or the hand where it stands if that is still far from its contacts (:meth:`~solver.ContactIK.far`:
the solve must then move it, while near them its fingers wrap along the walls), and only with solids to keep
the skin out of. The solve then goes on from the start kept with every term.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from geodesics.rigid import rigid_fit

#: Rounds of root fit and finger solve.
ROUNDS = 2
#: Evaluations of each round's finger solve.
FINGER_EVALUATIONS = 10
#: A start whose energy after a round exceeds the best's this many times goes no further: most lie
#: through the object (tens of thousands against hundreds), while a start that wins after the last round
#: was within five times the best after the first on every layout of the benchmark's hands.
PRUNE = 10.0
#: How far along the normals the second point of each contact lies, as a fraction of the hand's length.
NORMAL_OFFSET = 0.05
#: How far the curled start turns each joint that curls the pads (radians; at most to the joint's limit).
CURL = np.radians(60.0)
#: A joint curls the pads when it moves them along their normals: by at least this fraction of how far it
#: moves them at all (a finger's flexion, on any rig; its spread and twist move them sideways).
CURL_ALIGNMENT = 0.5

#: Evaluations of the whole hand's solve without the solids from the start kept (step 4).
UNSOLID_EVALUATIONS = 100

#: ``(θ (d,), DOFs (n,), evaluations) -> θ``: a solve of those DOFs without the solids' terms.
Descend = Callable[[np.ndarray, np.ndarray, int], np.ndarray]
#: ``θ (d,) -> energy`` with every term, reported as the solve's progress.
Judge = Callable[[np.ndarray], float]


def grasp_start(ik, theta: np.ndarray, index: np.ndarray, descend: Descend, judge: Judge) -> np.ndarray:
    """(d,) the start pose of a solve of ``ik`` (a :class:`~solver.ContactIK`) over the DOFs ``index``
    (n,) from θ (d,), found as the module docstring says; θ itself when the root is not free.

    ``descend`` solves some DOFs without the solids' terms, ``judge`` gives a pose's full energy (and
    reports it as progress, after each root fit too, so that a viewer sees the hand reach its contacts at
    once); the start with the lower energy is returned.
    """
    rig = ik.hand.rig
    root = index[rig.dof_bone[index] == 0]
    if root.size == 0:
        return theta
    fingers = index[rig.dof_bone[index] != 0]
    sizes = np.bincount(ik.patch_of)
    weights = 1.0 / sizes[ik.patch_of]
    starts = [theta]
    opened = theta.copy()
    opened[fingers] = rig.rest[fingers]
    if not np.array_equal(opened, theta):
        starts.append(rig.clip(opened))
    curled = _curled(ik, starts[-1], fingers, weights)
    if curled is not None:
        starts.append(curled)
    candidates = list(starts)
    if fingers.size:
        candidates.append(theta)  # the hand where it stands, its fingers solved
    stands = len(starts)
    energies = np.zeros(len(candidates))
    going = np.ones(len(candidates), bool)
    fitted = np.inf  # the lowest energy of a root fit
    for _ in range(ROUNDS):
        for i in np.flatnonzero(going):
            t = candidates[i]
            if i != stands:
                t = _root_fit(ik, t, root, weights)
                # the hand laid onto its contacts: a better pose to show at once
                fitted = min(fitted, judge(t))
            if fingers.size:
                t = descend(t, fingers, FINGER_EVALUATIONS)
            candidates[i], energies[i] = t, judge(t)
        going &= energies <= PRUNE * energies.min()
    if fingers.size and energies[stands] > fitted:
        # a root fit lies better: the hand stands through the object, not at its grasp
        energies[stands] = np.inf
    best = int(np.argmin(energies))
    if (best == stands and not ik.far(candidates[best])) or (ik.obstacle is None and ik.keep_out is None):
        return candidates[best]  # the hand at its grasp, only its fingers to wrap; or no solids
    grasp = descend(candidates[best], index, UNSOLID_EVALUATIONS)
    return grasp if judge(grasp) < energies[best] else candidates[best]


def _curled(ik, theta: np.ndarray, fingers: np.ndarray, weights: np.ndarray) -> np.ndarray | None:
    """θ with every DOF but the root's that carries the contacts along their normals (towards what they
    touch) turned by :data:`CURL` that way, as far as its limits allow; None when none does.

    On any rig these are the flexion of the fingers and of the wrist (which bends the forearm away from
    what the hand holds), and a joint beyond a pad turns so that its blended skin follows the pad; a
    finger's spread and twist carry the contacts sideways and stay. Each patch weighs alike
    (``weights``)."""
    rig = ik.hand.rig
    _, n, dp, _ = ik.hand.point_jacobian(theta, ik.hand_points)
    J = dp[:, :, fingers] * weights[:, None, None]
    along = np.einsum("kij,ki->j", J, n)
    moved = np.linalg.norm(J, axis=1).sum(axis=0)
    curls = rig.is_rotation[fingers] & (np.abs(along) >= CURL_ALIGNMENT * moved) & (moved > 0)
    if not np.any(curls):
        return None
    out = theta.copy()
    out[fingers[curls]] += CURL * np.sign(along[curls])
    return rig.clip(out)


def _root_fit(ik, theta: np.ndarray, root: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """θ with the root DOFs ``root`` moved by the rigid motion that best lays the contacts and their
    normals onto the targets and against the object's normals (step 1 of the module docstring)."""
    hand, rig = ik.hand, ik.hand.rig
    p, n = hand.posed_points(theta, ik.hand_points)
    offset = NORMAL_OFFSET * hand.length
    source = np.concatenate([p, p + offset * n])
    target = np.concatenate([ik.target_points, ik.target_points - offset * ik.target_normals])
    G = rigid_fit(source, target, np.concatenate([weights, weights])) @ rig.root_transform(theta)
    moved = theta.copy()
    moved[root] = rig.root_dofs(G, compatible=theta[3:6])[root]
    return rig.clip(moved)
