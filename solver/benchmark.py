"""Timings of the contact IK solver, and the ablation study of Contact Edit's Fig. 11.

:func:`run` returns benchmark rows (the ``contact-edit bench solver`` command prints them with
:func:`geodesics.benchmark.format_table`); :func:`ablation` returns the ablation rows, printed by
``contact-edit ablation`` with :func:`format_ablation`. The scenes are deterministic and shared with the
tests: :func:`cylinder_grasp` (a human hand closed around a cylinder by flex-to-contact) and
:func:`pole_wrap` (a tentacle's suction line wrapped around a thick pole).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from geodesics import SurfacePoints, TriMesh
from geodesics.benchmark import Row, median_time

from . import hands, objects
from .grasp import flex_to_contact, grasp
from .ik import ALGORITHMS, TRUST_REGION, ContactIK, Weights
from .rotations import axis_angle_to_matrix, euler_to_matrix, matrix_to_euler
from .sdf import MeshSDF

#: Contact points of the benchmark solve.
BENCH_CONTACTS = 2000
#: Finite-difference solves take seconds each: they are timed this many times at most, without warm-up.
FD_RUNS = 3
#: Poses per algorithm in the reliability column of the optimizer comparison.
RELIABILITY_POSES = 10
#: The optimizer the papers used (NLopt), which the ablation and the gradient comparison keep.
PAPER = "slsqp"


@dataclass(frozen=True)
class Scene:
    """A hand, an object and paired contacts: hand points (k), target points (k, 3) and normals (k, 3) on
    the object, and the (d,) pose ``theta`` the contacts were taken from."""

    hand: hands.Hand
    object: TriMesh
    sdf: MeshSDF
    points: SurfacePoints
    targets: np.ndarray
    normals: np.ndarray
    theta: np.ndarray  # the pose the contacts were taken from


def _lying_along_x(mesh: TriMesh, offset) -> TriMesh:
    """The mesh turned so that its z axis points along x, then moved by offset."""
    turn = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    return TriMesh(mesh.vertices @ turn.T + offset, mesh.faces)


def cylinder_grasp(points_per_patch: int = 60, seed: int = 2, within: float = 0.004) -> Scene:
    """A human hand closed around a cylinder under its palm by :func:`grasp`.

    The contacts are the hand's palm-side patch points (:meth:`Hand.contact_patches`) that end within
    ``within`` of the cylinder; their targets are the closest points on it, with its normals there.
    """
    hand = hands.make_hand("human")
    obj = _lying_along_x(
        objects.cylinder(radius=0.025, height=0.15, n_around=48, n_along=12), [0.025, 0.07, -0.058]
    )
    sdf = MeshSDF(obj)
    theta = grasp(hand, sdf).theta
    points = SurfacePoints.concatenate(hand.contact_patches(points_per_patch, seed=seed).values())
    positions, _ = hand.posed_points(theta, points)
    distance, closest, faces = sdf.query(positions)
    near = np.flatnonzero(np.abs(distance) < within)
    return Scene(hand, obj, sdf, points[near], closest[near], obj.face_normals[faces[near]], theta)


def pole_wrap(radius: float = 0.12, turns: float = 0.6) -> Scene:
    """A tentacle's suction line (its underside centre line) wrapped around a thick horizontal pole.

    The contacts are the tentacle's vertices on that line beyond 12 cm from its base; each one's target
    is on the pole at the same arc length around it, as if the line were laid on the pole, starting at
    the point of the pole nearest the tentacle at rest. ``theta`` is the rest pose.
    """
    hand = hands.make_hand("tentacle")
    V = hand.mesh.vertices
    line = np.flatnonzero((np.abs(V[:, 0]) < 1e-9 * hand.size) & (V[:, 2] < 0))
    line = line[np.argsort(V[line, 1])]
    start = 0.12
    thickness = -np.interp(start, V[line, 1], V[line, 2])
    centre = np.array([0.0, start, -(radius + thickness)])
    obj = _lying_along_x(objects.cylinder(radius=radius, height=0.4, n_around=96, n_along=8), centre)
    along = line[V[line, 1] > start]
    angle = (V[along, 1] - start) / (radius + thickness)
    along, angle = along[angle < 2 * np.pi * turns], angle[angle < 2 * np.pi * turns]
    normals = np.stack([np.zeros_like(angle), np.sin(angle), np.cos(angle)], 1)
    return Scene(
        hand,
        obj,
        MeshSDF(obj),
        SurfacePoints.from_vertices(hand.mesh, along),
        centre + radius * normals,
        normals,
        hand.rig.rest,
    )


def bench_problem(
    n_contacts: int = BENCH_CONTACTS, seed: int = 0
) -> tuple[hands.Hand, SurfacePoints, np.ndarray, np.ndarray, np.ndarray]:
    """The benchmark solve: the human hand (54 DOF), ``n_contacts`` palm-side points posed at the cylinder
    grasp with the root moved 2 cm and turned 10°; targets are those posed points with opposed normals.

    Returns the hand, the hand points (SurfacePoints (k), k = ``n_contacts``), the targets (k, 3), their
    normals (k, 3) and the (d,) ground-truth pose.
    """
    scene = cylinder_grasp()
    hand = scene.hand
    patches = hand.contact_patches(-(-n_contacts // 16), seed=seed)
    points = SurfacePoints.concatenate(patches.values())[:n_contacts]
    truth = scene.theta.copy()
    truth[:3] = [0.02, 0.0, 0.0]
    turn = axis_angle_to_matrix([np.radians(10.0), 1.0, 1.0, 0.0])
    truth[3:6] = matrix_to_euler(turn @ euler_to_matrix(truth[3:6]))
    positions, normals = hand.posed_points(truth, points)
    return hand, points, positions, -normals, truth


def _recovery_rate(algorithm: str, poses: int) -> int:
    """How many of ``poses`` random tentacle poses a solve from rest recovers (mean distance < 1 %)."""
    hand = hands.make_hand("tentacle")
    rig = hand.rig
    points = SurfacePoints.concatenate(hand.contact_patches(60, seed=0).values())
    ok = 0
    for seed in range(poses):
        truth = random_pose(rig, np.random.default_rng(seed))
        positions, normals = hand.posed_points(truth, points)
        start = perturbed_root(truth, np.random.default_rng(1000 + seed))
        result = ContactIK(hand, points, positions, -normals, algorithm=algorithm).solve(start)
        ok += bool(result.distances.mean() < 0.01 * hand.length)
    return ok


def random_pose(rig, rng: np.random.Generator) -> np.ndarray:
    """(d,) a random pose of ``rig``: joints uniform within their limits, the root anywhere within 5 cm and
    ±90° (each Euler angle)."""
    theta = np.zeros(rig.n_dofs)
    joints = rig.dof_bone != 0
    theta[joints] = rng.uniform(rig.lower[joints], rig.upper[joints])
    theta[:3] = rng.uniform(-0.05, 0.05, 3)
    theta[3:6] = rng.uniform(-np.pi / 2, np.pi / 2, 3)
    return theta


def perturbed_root(truth: np.ndarray, rng: np.random.Generator, shift: float = 0.02, degrees: float = 15.0):
    """(d,) the rest pose with the root of ``truth`` (d,) moved by up to ``shift`` and turned by up to
    ``degrees`` about a random axis (in the root's rest frame)."""
    start = np.zeros_like(truth)
    direction = rng.normal(size=3)
    start[:3] = truth[:3] + direction / np.linalg.norm(direction) * rng.uniform(0.0, shift)
    axis = rng.normal(size=3)
    turn = axis_angle_to_matrix(np.concatenate([[np.radians(rng.uniform(0.0, degrees))], axis]))
    start[3:6] = matrix_to_euler(turn @ euler_to_matrix(truth[3:6]), compatible=truth[3:6])
    return start


def run(
    repeat: int = 5,
    progress: Callable[[str], None] | None = None,
    contacts: int = BENCH_CONTACTS,
    reliability_poses: int = RELIABILITY_POSES,
) -> list[Row]:
    """Run the solver benchmarks; ``progress`` receives a line of text before each one."""
    say = progress or (lambda _msg: None)
    rows: list[Row] = []
    say("contact IK, analytic gradient")
    hand, points, targets, normals, _ = bench_problem(contacts)
    what = f"human hand, {hand.rig.n_dofs} DOF, {len(points):,} contacts, from rest"
    problem = ContactIK(hand, points, targets, normals)
    ours = median_time(problem.solve, repeat)
    result = problem.solve()
    rows.append(
        Row(
            f"contact IK ({problem.algorithm}, analytic gradient): {what}",
            ours,
            note=f"energy {result.energy:.6g} from {result.start_energy:.6g}; {result.iterations} "
            f"evaluations; mean contact distance {result.distances.mean() * 1e3:.2f} mm",
        )
    )
    paper = ContactIK(hand, points, targets, normals, algorithm=PAPER)
    paper_time = median_time(paper.solve, repeat)
    paper_result = paper.solve()
    for gradient, label in (("finite-difference", "forward"), ("central-difference", "central")):
        say(f"contact IK, {label} differences")
        fd_problem = ContactIK(hand, points, targets, normals, gradient=gradient)
        times = []
        for _ in range(min(repeat, FD_RUNS)):
            start = time.perf_counter()
            fd = fd_problem.solve()
            times.append(time.perf_counter() - start)
        peer = float(np.median(times))
        rows.append(
            Row(
                f"  same solve, {PAPER}, {label}-difference gradient (the papers')",
                paper_time,
                peer,
                f"{label} differences",
                f"the analytic gradient {peer / paper_time:.1f}x faster; energy {fd.energy:.6g} (rel. diff "
                f"{abs(paper_result.energy - fd.energy) / fd.energy:.1e}); {fd.iterations} evaluations",
            )
        )
    for name in (TRUST_REGION, *ALGORITHMS):
        say(f"optimizer {name}")
        solver = ContactIK(hand, points, targets, normals, algorithm=name)
        t = median_time(solver.solve, repeat)
        r = solver.solve()
        recovered = _recovery_rate(name, reliability_poses)
        rows.append(
            Row(
                f"  optimizer {name}: same solve",
                t,
                note=f"energy {r.energy:.6g}, {r.iterations} evaluations ({r.status}); tentacle pose "
                f"recovery {recovered}/{reliability_poses}",
            )
        )
    say("flex-to-contact")
    scene = cylinder_grasp()
    hand = scene.hand
    closed = grasp(hand, scene.sdf)
    t = median_time(lambda: grasp(hand, scene.sdf), repeat)
    touching = sum(closed.touching.values())
    rows.append(
        Row(
            f"flex-to-contact grasp: {len(hand.chains)} fingers, cylinder of {scene.object.n_faces} faces",
            t,
            note=f"{touching}/{len(hand.chains)} fingers touch; {closed.evaluations} pose evaluations",
        )
    )
    tip = SurfacePoints.from_vertices(hand.mesh, [int(np.argmax(hand.mesh.vertices[:, 1]))])
    dofs = hand.flexion_dofs("middle")
    t = median_time(lambda: flex_to_contact(hand, hand.rig.rest, dofs, tip, scene.sdf), repeat)
    flex = flex_to_contact(hand, hand.rig.rest, dofs, tip, scene.sdf)
    rows.append(
        Row(
            "flex-to-contact: middle fingertip to the cylinder",
            t,
            note=f"{flex.evaluations} evaluations; ends {flex.distance * 1e3:.3f} mm from the surface",
        )
    )
    return rows


# ------------------------------------------------------------------------------------------- ablation


@dataclass(frozen=True)
class AblationRow:
    """One solve of the ablation: which scene, which term was removed, and what came out."""

    scene: str
    variant: str
    distance: float  # mean contact distance, % of the hand's length
    normal: float  # mean n . m over contacts (-1: perfectly opposed)
    deviation: float  # mean |θ - rest| over joint DOFs, degrees
    max_deviation: float  # degrees
    penetration: float  # deepest hand vertex inside the object, mm
    wrong_side: int  # segments whose axis ends up inside the object


#: The ablation's variants: each removes one term of Eq. 2.
VARIANTS = {
    "full": Weights(),
    "no distance (λd = 0)": Weights(d=0.0),
    "no normal (λn = 0)": Weights(n=0.0),
    "no prior (λp = 0)": Weights(p=0.0),
}


def _evaluate(scene: Scene, name: str, variant: str, theta: np.ndarray) -> AblationRow:
    hand, rig = scene.hand, scene.hand.rig
    p, n = hand.posed_points(theta, scene.points)
    joints = np.degrees(np.abs(theta[rig.dof_bone != 0] - rig.rest[rig.dof_bone != 0]))
    mats = rig.pose_matrices(theta)
    middles = mats[:, :3, 3] + 0.5 * rig.lengths[:, None] * mats[:, :3, 1]
    return AblationRow(
        scene=name,
        variant=variant,
        distance=100 * float(np.linalg.norm(p - scene.targets, axis=1).mean()) / hand.length,
        normal=float(np.einsum("ij,ij->i", n, scene.normals).mean()),
        deviation=float(joints.mean()),
        max_deviation=float(joints.max()),
        penetration=1e3 * max(0.0, -float(scene.sdf(hand.posed_vertices(theta)).min())),
        wrong_side=int(np.sum(scene.sdf(middles[1:]) < 0)),
    )


def ablation(progress: Callable[[str], None] | None = None) -> list[AblationRow]:
    """Solve two scenes from the rest pose with each term of Eq. 2 removed in turn (Fig. 11), as the paper
    solves: NLopt's SLSQP from the given pose (no global start)."""
    say = progress or (lambda _msg: None)
    rows = []
    for name, scene in (
        ("human hand, cylinder grasp", cylinder_grasp()),
        ("tentacle, wrap around a pole", pole_wrap()),
    ):
        for variant, weights in VARIANTS.items():
            say(f"{name}: {variant}")
            ik = ContactIK(scene.hand, scene.points, scene.targets, scene.normals, weights, algorithm=PAPER)
            result = ik.solve(start="local")
            rows.append(_evaluate(scene, name, variant, result.theta))
    return rows


def format_ablation(rows: list[AblationRow]) -> str:
    """A plain-text table of the ablation rows."""
    lines = [
        f"{'scene':30} {'variant':22} {'distance':>9} {'n.m':>6} {'joint dev':>10} {'max dev':>8} "
        f"{'penetr.':>8} {'wrong side':>10}",
        f"{'':30} {'':22} {'% length':>9} {'mean':>6} {'mean deg':>10} {'deg':>8} {'mm':>8} {'segments':>10}",
    ]
    for r in rows:
        lines.append(
            f"{r.scene:30} {r.variant:22} {r.distance:9.2f} {r.normal:6.2f} {r.deviation:10.1f} "
            f"{r.max_deviation:8.1f} {r.penetration:8.1f} {r.wrong_side:10d}"
        )
    return "\n".join(lines)
