"""Contact IK for a Blender scene: the hand's paired patches, the object's, and the armature to pose.

Shared by the solve and flex-to-contact operators and the batch commands, so that an animator's click
and a script pose the same way. Geometry is gathered once into armature space (see
:mod:`.bridge.armature`); solving is then pure numpy, which is why the operator can run it in a worker
thread and redraw the viewport as the pose improves.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import bpy
import numpy as np

from geodesics import ContactError, SurfacePoints, TriMesh
from solver import (
    TOUCH_DISTANCE,
    ContactIK,
    GraspResult,
    Hand,
    MeshSDF,
    SolverError,
    SolveResult,
    Weights,
    grasp,
)
from solver.sdf import deepest_in_faces

from . import bridge, store

#: Which DOFs a solve may change (the paper's staged solves: the root first, then everything).
STAGES = (
    ("ROOT", "Root only", "Move and turn the whole hand by its root control; no finger changes"),
    ("FINGERS", "Fingers only", "Every control under the hand root; the hand stays where it is"),
    ("ALL", "All controls", "The hand's root control and every control under the hand root"),
    ("SELECTED", "Selected controls", "Only the controls selected in Pose Mode"),
)
#: Where a solve starts (:data:`solver.ik.STARTS`), as the Solve operator offers it.
STARTS = (
    (
        "AUTO",
        "Auto",
        "From the grasp the contacts imply when the hand is far from them, else from the hand's pose "
        "(an edit of a solved layout stays near)",
    ),
    ("FRESH", "Fresh", "From the grasp the contacts imply, wherever the hand is (it may turn and travel)"),
    ("POSE", "From the pose", "From the hand's pose only, as Contact Edit solves"),
)
#: The solver's name for each start.
START_MODES = {"AUTO": "auto", "FRESH": "global", "POSE": "local"}


@dataclass(frozen=True)
class Problem:
    """One contact IK solve set up from the scene.

    ``pairs`` lists the (hand patch, object patch) names whose points were paired, ``sizes`` how many
    contacts each pair has (in the order of ``ik``'s points); ``free`` the DOFs the stage lets change;
    ``world_scale`` converts armature-space lengths into scene units; ``target`` names the object and
    ``solid`` is its signed distance in armature space (None if it has no inside; see
    :func:`object_solid`), kept out of when λo > 0 and always measured.
    """

    posed: bridge.PosedHand
    ik: ContactIK
    theta0: np.ndarray
    free: np.ndarray
    pairs: tuple[tuple[str, str], ...]
    sizes: tuple[int, ...]
    world_scale: float
    target: str
    solid: MeshSDF | None

    def apply(self, theta, frame: int | None = None) -> None:
        bridge.apply_pose(self.posed, theta, frame)


def _objects(scene: bpy.types.Scene) -> tuple[bpy.types.Object, bpy.types.Object]:
    settings = scene.contact_edit
    if settings.hand is None or settings.target is None:
        raise bridge.BridgeError("choose the hand and the object in the Contact tab first")
    same = of_the_hand(settings.hand, settings.target)
    if same is not None:
        raise bridge.BridgeError(
            f"the object '{settings.target.name}' is {same}; choose the mesh the hand touches as the object"
        )
    return settings.hand, settings.target


def of_the_hand(hand: bpy.types.Object, target: bpy.types.Object) -> str | None:
    """What ``target`` is of the hand, in words, when it is the hand itself or the armature that deforms
    it (a solve would pose the hand against its own skin: nothing to touch); None for any other object."""
    if target == hand:
        return "the hand itself"
    if target == hand.find_armature() or (target.type == "ARMATURE" and target == hand.parent):
        return "the hand's armature"
    return None


def contact_pairs(hand_set, object_set) -> tuple[SurfacePoints, SurfacePoints, list[tuple[str, str]]]:
    """The hand's points and the object's points they pair with, over all paired patches."""
    pairs = [(h, o) for h, o in hand_set.pairs.items() if o in object_set]
    if not pairs:
        raise ContactError(
            "no hand patch is paired with a patch of the object; transfer hand patches onto it first"
        )
    hand_points, object_points = [], []
    for h, o in pairs:
        a, b = hand_set[h].points, object_set[o].points
        if len(a) != len(b):
            raise ContactError(
                f"the paired patches '{h}' ({len(a)} points) and '{o}' ({len(b)} points) do not match "
                "point for point; transfer the hand patch again"
            )
        hand_points.append(a)
        object_points.append(b)
    return SurfacePoints.concatenate(hand_points), SurfacePoints.concatenate(object_points), pairs


def object_in_armature(target: bpy.types.Object, posed: bridge.PosedHand) -> np.ndarray:
    """(4, 4) the object's space to the armature's."""
    armature = posed.armature_object()
    return np.linalg.inv(np.array(armature.matrix_world)) @ np.array(target.matrix_world)


def object_solid(mesh: TriMesh, to_armature: np.ndarray) -> MeshSDF | None:
    """The object's signed distance in armature space, for keeping the hand out of it. None for an open
    mesh (a plane, a scan with holes), which has no inside, and for an inside-out one (a mould, a room:
    its faces point in), whose "inside" is all the space around it, where the hand starts."""
    if np.any(mesh.twin < 0) or mesh.signed_volume <= 0:
        return None
    return MeshSDF(bridge.moved_solid(mesh, to_armature))


def problem(scene: bpy.types.Scene, stage: str = "ALL") -> Problem:
    """Set up the contact IK of the scene's hand and object from their stored, paired contacts.

    Raises BridgeError, ContactError or SolverError with what to fix.
    """
    hand, target = _objects(scene)
    settings = scene.contact_edit
    hand_set = store.load(hand, settings.deformed, layer="CONTACTS")
    object_set = store.load(target, layer="CONTACTS")
    hand_points, object_points, pairs = contact_pairs(hand_set, object_set)
    posed = bridge.posed_hand(hand, hand_set.mesh.faces, hand_points, settings.hand_root)
    _reports[scene.name] = describe_plan(posed.plan, hand)
    M = object_in_armature(target, posed)
    positions = object_points.positions(object_set.mesh) @ M[:3, :3].T + M[:3, 3]
    normals = object_set.mesh.face_normals[object_points.faces] @ np.linalg.inv(M[:3, :3])
    weights = Weights(
        d=settings.weight_distance, n=settings.weight_normal, p=settings.weight_prior,
        o=settings.weight_penetration,
    )  # fmt: skip
    solid = object_solid(object_set.mesh, M)
    keep_out = solid if settings.weight_penetration > 0 else None
    sizes = tuple(len(hand_set[h]) for h, _ in pairs)
    patches = [(h, size) for (h, _), size in zip(pairs, sizes, strict=True)]
    ik = ContactIK(posed.skin, hand_points, positions, normals, weights, keep_out=keep_out, patches=patches)
    armature = posed.armature_object()
    return Problem(
        posed=posed,
        ik=ik,
        theta0=posed.start,
        free=free_dofs(posed, armature, stage),
        pairs=tuple(pairs),
        sizes=sizes,
        world_scale=bridge.uniform_scale(armature),
        target=target.name,
        solid=solid,
    )


def free_dofs(posed: bridge.PosedHand, armature: bpy.types.Object, stage: str) -> np.ndarray:
    """(d,) bool: the DOFs a stage lets the solve change."""
    rig = posed.rig
    if stage == "ROOT":
        return rig.dof_bone == 0
    if stage == "FINGERS":
        return rig.dof_bone != 0
    if stage == "ALL":
        return np.ones(rig.n_dofs, bool)
    if stage == "SELECTED":
        chosen = bridge.selected_bones(armature)
        selected = [b for b, name in enumerate(rig.names) if name in chosen]
        if not selected:
            raise bridge.BridgeError(
                f"no control the solve poses is selected in '{armature.name}' (they are "
                f"{', '.join(rig.names[:4])}{', …' if rig.n_bones > 4 else ''}); select some in Pose Mode, "
                "or solve all controls"
            )
        return np.isin(rig.dof_bone, selected)
    raise ValueError(f"unknown stage {stage!r}; use one of {', '.join(s[0] for s in STAGES)}")


#: How the panel and reports say how a solve ended (SolveResult.status, or "kept" when the user stopped it).
OUTCOMES = {
    "converged": "converged",
    "max evaluations": "stopped at the evaluation limit",
    "stopped": "stopped: no further progress",
    "cancelled": "cancelled",
    "kept": "stopped by you; kept the best pose",
    "no free DOFs": "nothing to solve: every control it may move is locked",
    "unchanged": "the pose did not change",
}
#: Outcomes that are warnings, not a result.
WARNINGS = {"no free DOFs", "unchanged"}


#: The skin Blender shows after a solve may differ from the solver's by this much of the hand's size
#: (float32 rounding) before the solve says the rig did not follow.
FOLLOW_TOLERANCE = 1e-4


def rig_mismatch(scene: bpy.types.Scene, problem: Problem, theta) -> str | None:
    """After writing a pose back: None when Blender's skin is the solver's, else how far it is off (an
    IK arm that cannot reach, a rig changed since the solve started)."""
    off = bridge.deviation(problem.posed, theta)
    if off <= FOLLOW_TOLERANCE * problem.posed.skin.size:
        return None
    approximated = problem.posed.plan.approximated
    later = [
        m.name for m in bridge.after_armature(bpy.data.objects[problem.posed.hand]) if m.type not in REFINING
    ]
    reasons = [f"{', '.join(approximated[:2])} taken to follow the hand"] if approximated else []
    reasons += [f"{', '.join(later)} after the Armature modifier"] if later else []
    why = f" ({'; '.join(reasons)})" if reasons else ""
    return (
        f"the rig's skin ends up to {length_text(scene, off * problem.world_scale)} from the solved pose{why}"
    )


#: After a solve, rounds of letting Blender's IK place the arm and solving again from there, and the
#: evaluations each round may take.
SETTLE_ROUNDS, SETTLE_EVALUATIONS = 3, 60


def settle(
    scene: bpy.types.Scene, solved: Problem, result: SolveResult, stage: str = "ALL", frame: int | None = None
) -> tuple[Problem, SolveResult]:
    """Write the solved pose back (keyed at ``frame`` if given), and where bones were taken to follow the
    hand rigidly (an IK arm, which Blender's IK bends instead) and Blender's skin is therefore not the
    solver's: read the rig again where Blender's IK put the arm, and solve again from there, a few
    evaluations, until the two agree (60 mm apart after a hand length's move, 0.5 mm after one round).

    Returns the problem of the pose written last and its result (evaluations and seconds summed over the
    rounds, the first solve's status).
    """
    solved.apply(result.theta, frame)
    for _ in range(SETTLE_ROUNDS):
        if not solved.posed.plan.approximated or rig_mismatch(scene, solved, result.theta) is None:
            break
        solved = problem(scene, stage)
        again = solved.ik.solve(solved.theta0, solved.free, max_evaluations=SETTLE_EVALUATIONS, start="local")
        result = replace(
            again,
            iterations=result.iterations + again.iterations,
            seconds=result.seconds + again.seconds,
            status=result.status,
        )
        solved.apply(result.theta, frame)
    return solved, result


def length_text(scene: bpy.types.Scene, value: float) -> str:
    """A length in scene units as the scene displays it (e.g. '1.2 mm')."""
    units = scene.unit_settings
    if units.system == "NONE":
        return f"{value:.4g}"
    return bpy.utils.units.to_string(units.system, "LENGTH", value * units.scale_length, precision=3)


@dataclass(frozen=True)
class Touch:
    """How a solved pose meets the object, measured, never assumed.

    ``gaps`` holds each paired hand patch's median contact distance to its targets (scene units),
    ``touching`` the patches whose gap is within ``tolerance``; ``deepest`` is how far the deepest
    vertex of the hand's skin is inside the object (0 when none is; None for an open object, which
    has no inside). Between vertices a face can cut a sharp edge of the object (a mug's rim) a little
    deeper: ``deepest_face`` is how deep the skin's faces go (:func:`solver.sdf.deepest_in_faces`), when
    asked for (else None, as for an open object).
    """

    gaps: dict[str, float]
    touching: tuple[str, ...]
    tolerance: float
    deepest: float | None
    deepest_face: float | None = None


def touch(problem: Problem, theta, faces: bool = False) -> Touch:
    """Which paired hand patches the pose θ (d,) brings onto the object, and how deep it is inside: its
    deepest vertex, and with ``faces`` the deepest point of its faces."""
    scale = problem.world_scale
    gaps = {h: gap * scale for h, gap in problem.ik.gaps(theta).items()}
    tolerance = TOUCH_DISTANCE * problem.ik.unit * scale
    deepest = deepest_face = None
    if problem.solid is not None:
        skin = problem.ik.hand.posed_vertices(theta)
        deepest = max(0.0, -float(problem.solid(skin).min())) * scale
        if faces:
            deepest_face = deepest_in_faces(problem.solid, skin, problem.ik.hand.mesh.faces) * scale
    touching = tuple(h for h, gap in gaps.items() if gap <= tolerance)
    return Touch(gaps, touching, tolerance, deepest, deepest_face)


def summary(scene: bpy.types.Scene, problem: Problem, result: SolveResult, outcome: str | None = None) -> str:
    """How the solve went, in clauses separated by '; ' (the panel puts one per line): contacts, how
    close they got, which patches touch and how deep the hand is in the object (:func:`touch`),
    evaluations, time and outcome."""
    mean = float(result.distances.mean()) * problem.world_scale
    worst = float(result.distances.max()) * problem.world_scale
    met = touch(problem, result.theta)
    off = [f"{h} {length_text(scene, gap)} off" for h, gap in met.gaps.items() if h not in met.touching]
    touching = (
        f"all {len(met.gaps)} patches touch '{problem.target}'"
        if not off
        else f"{len(met.touching)} of {len(met.gaps)} patches touch '{problem.target}' ({', '.join(off)})"
    )
    clauses = [
        f"{len(result.distances)} contacts in {len(problem.pairs)} patch pairs",
        f"mean distance {length_text(scene, mean)}, largest {length_text(scene, worst)}",
        touching,
    ]
    if met.deepest is not None:
        clauses.append(
            f"deepest vertex {length_text(scene, met.deepest)} inside '{problem.target}'"
            if met.deepest > 0
            else f"no skin inside '{problem.target}'"
        )
    if len(result.out_of_reach) == 1 and len(problem.pairs) > 1:
        (name,) = result.out_of_reach
        gap = length_text(scene, result.gaps[name] * problem.world_scale)
        clauses.append(f"{name} cannot be reached with the others: it stays {gap} off")
    clauses.append(
        f"{result.iterations} evaluations in {result.seconds:.2f} s, {OUTCOMES[outcome or result.status]}"
    )
    return "; ".join(clauses)


@dataclass(frozen=True)
class RigReport:
    """What the panel says about the hand's rig: whether it can be solved, and in a few short lines how
    (the wrist, the control that moves it, the controls under it) or what blocks it."""

    ok: bool
    lines: tuple[str, ...]


#: The last report per scene, computed when the hand or its root changes and with each solve.
_reports: dict[str, RigReport] = {}


def rig_report(scene: bpy.types.Scene) -> RigReport | None:
    """The last :func:`check_rig` of the scene's hand, if any."""
    return _reports.get(scene.name)


def check_rig(scene: bpy.types.Scene) -> RigReport:
    """Read the hand's rig and say whether contact IK can pose it, before anything is painted or solved."""
    settings = scene.contact_edit
    hand = settings.hand
    if hand is None:
        _reports.pop(scene.name, None)
        return RigReport(False, ("Choose the hand",))
    try:
        contacts = store.load(hand, layer="CONTACTS")
        points = [contacts[name].points for name in contacts]
        rig = bridge.hand_rig(hand)
        plan = bridge.hand_plan(
            rig,
            contacts.mesh.faces,
            SurfacePoints.concatenate(points) if points else None,
            settings.hand_root,
        )
        report = describe_plan(plan, hand)
    except (bridge.BridgeError, ContactError, SolverError) as err:
        report = RigReport(False, (str(err),))
    _reports[scene.name] = report
    return report


@bpy.app.handlers.persistent
def _check_rigs_after_load(*_args) -> None:
    """Say how each scene's hand is solved as soon as a file is open, as when the hand was chosen (the
    reports are not saved: the Rig box was empty until the hand was chosen again)."""
    _reports.clear()
    for scene in bpy.data.scenes:
        if scene.contact_edit.hand is not None:
            check_rig(scene)


def register() -> None:
    bpy.app.handlers.load_post.append(_check_rigs_after_load)


def unregister() -> None:
    if _check_rigs_after_load in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.remove(_check_rigs_after_load)


#: Modifiers after the Armature modifier that only refine, re-triangulate, mirror or re-shade the skin it
#: deforms: the solve works on that skin (the cage) and Blender shows it as they make it.
REFINING = {"SUBSURF", "TRIANGULATE", "WEIGHTED_NORMAL", "NORMAL_EDIT", "MIRROR", "EDGE_SPLIT"}


def describe_plan(plan, hand: bpy.types.Object | None = None) -> RigReport:
    """The panel's lines for a :class:`solver.rig.controls.Plan` (and the modifiers of ``hand`` after its
    Armature modifier: what is solved on the cage they refine, and what moves the skin unmodelled)."""
    lines = [f"Wrist: {plan.hand_root}"]
    if plan.root is None:
        lines.append("Nothing moves the wrist; only the fingers are solved")
    else:
        root = plan.armature[plan.root]
        turns = not all(root.lock_rotation)
        moves = not all(root.lock_location) and not root.bone.use_connect
        lines.append(f"{plan.root} {'moves and turns' if moves else 'turns' if turns else 'holds'} the hand")
        if turns and not moves:
            lines.append("(its location is locked; an IK hand control can move it)")
    lines.append(f"{len(plan.controls)} controls under the wrist")
    if plan.approximated:
        shown = ", ".join(plan.approximated[:2]) + (", …" if len(plan.approximated) > 2 else "")
        lines.append(f"Taken to follow the hand rigidly: {shown}")
    later = bridge.after_armature(hand) if hand is not None else []
    refining = [m.name for m in later if m.type in REFINING]
    moving = [m.name for m in later if m.type not in REFINING]
    if refining:
        lines.append(f"Solved on the skin before {', '.join(refining)}")
    if moving:
        lines.append(f"Not modelled: {', '.join(moving)} after the Armature modifier")
    for blocker in plan.blockers[:4]:
        lines.append(f"Blocked: {blocker}")
    if len(plan.blockers) > 4:
        lines.append(f"… {len(plan.blockers) - 4} more")
    return RigReport(plan.ok, tuple(lines))


def flex(
    scene: bpy.types.Scene, direction: int = 1, curl: str = "together"
) -> tuple[bridge.PosedHand, GraspResult]:
    """Curl each chain of selected bones until it touches the object (flex-to-contact, 1988).

    A chain is a selected bone and its selected descendants, each curling about its x axis towards
    the limit on the ``direction`` side (+1: positive angles), its joints ``"together"`` or ``"in
    turn"`` from the first (see :func:`solver.grasp`). The object must be closed. Returns the posed hand
    and the grasp: its pose, and for each chain (named by its first bone) how far it is from the
    object and whether it touches.
    """
    hand, target = _objects(scene)
    settings = scene.contact_edit
    hand_set = store.load(hand, settings.deformed, layer="CONTACTS")
    posed = bridge.posed_hand(hand, hand_set.mesh.faces, hand_root=settings.hand_root)
    armature = posed.armature_object()
    rig = posed.rig
    chosen = bridge.selected_bones(armature)
    selected = [b for b, name in enumerate(rig.names) if b > 0 and name in chosen]
    if not selected:
        raise bridge.BridgeError(
            f"select the finger controls to curl in Pose Mode (controls of '{armature.name}' under the "
            f"hand root, such as {', '.join(rig.names[1:4]) or 'none'})"
        )
    chains = _chains(rig.parents, selected)
    inside = bridge.moved_solid(bridge.trimesh(target), object_in_armature(target, posed))
    skin = posed.skin
    manipulator = Hand(
        skin.mesh, rig, skin.weights, kind=f"'{hand.name}'", length=skin.size,
        chains={rig.names[c[0]]: c for c in chains},
    )  # fmt: skip
    return posed, grasp(manipulator, inside, posed.start, direction=direction, curl=curl)


def _chains(parents: np.ndarray, selected: list[int]) -> list[tuple[int, ...]]:
    """Selected bones grouped into chains: a chain runs on through a bone's selected child when it has
    exactly one; every other selected bone starts a chain (so selecting the palm and all fingers gives
    the palm and each finger)."""
    children = {b: [c for c in selected if int(parents[c]) == b] for b in selected}
    continues = {kids[0] for kids in children.values() if len(kids) == 1}
    chains = []
    for b in selected:
        if b in continues:
            continue
        chain = [b]
        while len(children[chain[-1]]) == 1:
            chain.append(children[chain[-1]][0])
        chains.append(tuple(chain))
    return chains
