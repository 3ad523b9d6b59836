"""``contact-edit bench rigs``: contact IK on a Rigify hand beside the same contacts on the procedural human
hand, whose mesh the Rigify hand skins (:mod:`..assets.rigify`): the cost of posing a production rig through
its controls, constraints and B-Bones instead of a plain tree of bones.

Both hands carry the same palm-side contact points of one mesh. Each solve starts from the pose the hand
was read in and recovers a seeded random pose of its DOFs (the fingers turned by up to 0.45 rad about
each axis, the root moved by up to 2 cm and turned by up to 0.25 rad where it may move).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import bpy
import numpy as np

from geodesics import SurfacePoints, benchmark
from solver import ContactIK, SkinnedMesh, hands

from .. import bridge
from ..assets import rigify

#: Palm-side points per patch (16 patches: about 1,900 contacts, the paper's contact count).
POINTS_PER_PATCH = 120
#: Energy evaluations timed per figure.
EVALUATIONS = 20


def random_controls(start: np.ndarray, locked: np.ndarray, n_bones: int, rng) -> np.ndarray:
    """A seeded random pose of a hand's DOFs around ``start`` (see the module's docstring)."""
    theta = start.copy()
    theta[6:] += rng.uniform(-0.45, 0.45, theta.size - 6) * np.tile([1.0, 1 / 3, 1.0], n_bones - 1)
    theta[:3] += rng.uniform(-0.02, 0.02, 3)
    theta[3:6] += rng.uniform(-0.25, 0.25, 3)
    return np.where(locked, start, theta)


def _energy_time(ik: ContactIK, theta: np.ndarray, with_gradient: bool) -> float:
    """Median time of one evaluation as a solve makes it (the gradient for the free DOFs only)."""
    free = np.flatnonzero(~ik.hand.rig.locked)
    times = []
    for _ in range(EVALUATIONS):
        t = time.perf_counter()
        ik.energy_and_gradient(theta, dofs=free) if with_gradient else ik.energy(theta)
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def _solves(
    skin: SkinnedMesh, points: SurfacePoints, start: np.ndarray, repeat: int
) -> tuple[float, int, float]:
    """Median solve time, median evaluations and worst mean contact distance over ``repeat`` poses."""
    rig = skin.rig
    seconds, evaluations, worst = [], [], 0.0
    for seed in range(repeat):
        truth = rig.clip(random_controls(start, rig.locked, rig.n_bones, np.random.default_rng(seed)))
        targets, normals = skin.posed_points(truth, points)
        result = ContactIK(skin, points, targets, -normals).solve(start)
        seconds.append(result.seconds)
        evaluations.append(result.iterations)
        worst = max(worst, float(result.distances.mean()))
    return float(np.median(seconds)), int(np.median(evaluations)), worst


def run(repeat: int = 5, progress: Callable[[str], None] | None = None) -> list[benchmark.Row]:
    """The benchmark's rows: per Rigify arm mode, energy evaluations and solves beside the procedural hand."""
    say = progress or (lambda _message: None)
    say("building the Rigify human with the procedural hand (Rigify's Generate Rig takes a while)")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    hand_obj, rig_obj = rigify.rigify_hand(bpy.context.scene.collection)
    kit = hands.make_hand("human")
    points = SurfacePoints.concatenate(kit.contact_patches(POINTS_PER_PATCH, seed=0).values())
    faces = bridge.trimesh(hand_obj).faces
    start = kit.rig.rest
    truth = kit.rig.clip(random_controls(start, kit.rig.locked, kit.rig.n_bones, np.random.default_rng(99)))
    targets, normals = kit.posed_points(truth, points)
    plain = ContactIK(kit, points, targets, -normals)
    say("timing the procedural hand")
    peer = {
        "gradient": _energy_time(plain, start, True),
        "energy": _energy_time(plain, start, False),
        "solve": _solves(kit, points, start, repeat),
    }
    rows = []
    for mode, ik_fk in (("FK", 1.0), ("IK", 0.0)):
        say(f"timing the Rigify hand, arm in {mode}")
        rig_obj.pose.bones["upper_arm_parent.R"]["IK_FK"] = ik_fk
        rig_obj.update_tag()
        bpy.context.view_layer.update()
        posed = bridge.posed_hand(hand_obj, faces, points)
        rig = posed.rig
        goal = rig.clip(random_controls(rig.start, rig.locked, rig.n_bones, np.random.default_rng(99)))
        targets, normals = posed.skin.posed_points(goal, points)
        ik = ContactIK(posed.skin, points, targets, -normals)
        free = rig.n_dofs - int(rig.locked.sum())
        what = f"Rigify hand, arm in {mode} ({free} free DOF, {len(points)} contacts)"
        peer_name = f"procedural human hand ({kit.rig.n_dofs} DOF)"
        solve, evaluations, worst = _solves(posed.skin, points, rig.start, repeat)
        rows += [
            benchmark.Row(
                f"{what}: energy and gradient", _energy_time(ik, rig.start, True), peer["gradient"], peer_name
            ),
            benchmark.Row(f"{what}: energy", _energy_time(ik, rig.start, False), peer["energy"], peer_name),
            benchmark.Row(
                f"{what}: solve from the pose read",
                solve,
                peer["solve"][0],
                peer_name,
                f"{evaluations} vs {peer['solve'][1]} evaluations; worst mean contact distance "
                f"{1e3 * worst:.2f} vs {1e3 * peer['solve'][2]:.2f} mm",
            ),
        ]
    return rows
