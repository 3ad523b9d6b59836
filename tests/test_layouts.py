"""Person-like contact layouts (solver.layouts) and the benchmark they drive (solver.layout_benchmark).

Oracles: the object's own signed distance (targets taken from a grip lie on the surface); the cylinder's
side is developable, so a straightest geodesic of length s ends exactly s from where it started (the
exact log map measures it); the known grip carried by the layout's rigid motion is a pose that meets its
unslid targets, so the judge must pass it, and the hand left at rest must fail. Grips are made once per
session (flex-to-contact takes a second each).
"""

import numpy as np
import pytest

from geodesics import TriMesh, log_map
from solver import SkinnedMesh, SolverError, hands
from solver import layout_benchmark as bench
from solver import layouts as L
from solver.rotations import axis_angle_to_matrix


@pytest.fixture(scope="module")
def human():
    return hands.make_hand("human")


@pytest.fixture(scope="module")
def grips(human):
    return {name: L.known_grip(human, name) for name in L.OBJECTS}


@pytest.fixture(scope="module")
def cylinder(grips):
    return grips["cylinder"]


def test_grips_are_person_like(grips, human):
    """Every object gives the human hand a usable grip: fingertip pads first, each pad's points within
    the contact threshold of the object in the grip, at most one pad per digit."""
    for grip in grips.values():
        assert grip.usable and 2 <= len(grip.pads) <= L.MAX_PADS
        assert np.all(np.diff(grip.pad_index) >= 0) and grip.pad_index.max() == len(grip.pads) - 1
        posed, _ = human.posed_points(grip.theta, grip.points)
        assert np.abs(grip.sdf(posed)).max() <= L.CONTACT
        digits = [next(c for c, bones in human.chains.items() if human.rig.bone_index(p) in bones)
                  for p in grip.pads if p != "hand"]  # fmt: skip
        assert len(digits) == len(set(digits))
    assert all(p.endswith("_3") for p in grips["mug"].pads if not p.startswith("thumb"))


def test_unslid_targets_lie_on_the_surface(cylinder, grips):
    for grip in (cylinder, grips["mug"]):
        layout = L.make_layout(grip, L.BINS[1], seed=3, slide=(0.0, 0.0))
        assert np.abs(layout.sdf(layout.positions)).max() < 1e-9
        assert np.allclose(layout.positions, layout.targets.positions(layout.object), atol=0)
        assert np.allclose(np.linalg.norm(layout.normals, axis=1), 1.0)


def test_slide_moves_each_pad_by_its_length_on_the_cylinder_side(cylinder):
    """On the developable side of the cylinder each target ends exactly |slide| of its pad away (the
    exact geodesic distance), for targets whose slide stays clear of the rims (cone points)."""
    slid = L.make_layout(cylinder, L.BINS[0], seed=5)
    unslid = L.make_layout(cylinder, L.BINS[0], seed=5, slide=(0.0, 0.0))
    assert np.allclose(slid.motion, unslid.motion, atol=0)  # the slide draws do not change the motion
    lengths = np.abs(slid.slides)
    assert np.all((lengths >= L.SLIDE[0]) & (lengths <= L.SLIDE[1]))
    mesh, V = slid.object, slid.object.vertices
    axis = (V[-1] - V[-2]) / np.linalg.norm(V[-1] - V[-2])  # the cap centres are the last two vertices
    along = (slid.positions - 0.5 * (V[-1] + V[-2])) @ axis
    clear = np.flatnonzero(np.abs(along) < 0.075 - 2 * L.SLIDE[1])
    assert clear.size > 0.8 * len(slid.positions)
    distances = np.array([abs(log_map(mesh, unslid.targets[int(i)], slid.targets[int(i)])[0]) for i in clear])
    assert np.allclose(distances, lengths[slid.pad_index[clear]], rtol=0, atol=1e-9)


@pytest.mark.parametrize("bin", L.BINS)
def test_motion_turns_within_its_bin_and_moves_at_most_a_hand_length(cylinder, human, bin):
    for seed in range(4):
        layout = L.make_layout(cylinder, bin, seed=seed)
        assert bin[0] - 1e-9 <= layout.angle <= bin[1] + 1e-9
        assert layout.shift <= human.length
        G = layout.motion
        assert np.allclose(G[:3, :3] @ G[:3, :3].T, np.eye(3), atol=1e-12)
        assert np.allclose(
            cylinder.object.vertices @ G[:3, :3].T + G[:3, 3], layout.object.vertices, atol=1e-15
        )


def test_turned_by_zero_is_the_identity_and_by_25_degrees_an_isometry(cylinder):
    layout = L.make_layout(cylinder, L.BINS[2], seed=1)
    same = L.turned(layout, 0, 0.0)
    assert np.allclose(same.positions, layout.positions, rtol=0, atol=1e-10)
    pad = len(layout.pads) - 1
    turned = L.turned(layout, layout.pads[pad], 25.0)
    rows = np.flatnonzero(layout.pad_index == pad)
    others = np.flatnonzero(layout.pad_index != pad)
    assert np.array_equal(turned.positions[others], layout.positions[others])
    centre = layout.targets[int(layout.centres[pad])]
    before = log_map(layout.object, centre, layout.targets[rows])
    after = log_map(turned.object, centre, turned.targets[rows])
    assert np.allclose(np.abs(after), np.abs(before), rtol=0, atol=1e-9)
    away = np.abs(before) > 1e-4
    assert np.allclose(after[away] / before[away] * np.abs(before[away] / after[away]),
                       np.exp(1j * np.radians(25.0)), atol=1e-6)  # fmt: skip
    assert np.abs(turned.sdf(turned.positions)).max() < 1e-9
    assert np.allclose(turned.normals, turned.object.face_normals[turned.targets.faces])


def test_the_known_grip_passes_its_judge_and_rest_fails(grips, human):
    for grip in grips.values():
        layout = L.make_layout(grip, L.BINS[2], seed=7)
        verdict = L.judge(human, layout.reference, layout)
        assert verdict.touching.all() and verdict.contact.max() <= L.CONTACT
        assert verdict.depth <= L.DEPTH
        assert verdict.success  # the slide (≤ 5 mm) keeps the pads within reach of their patches
        exact = L.make_layout(grip, L.BINS[2], seed=7, slide=(0.0, 0.0))
        assert L.judge(human, exact.reference, exact).reach.max() <= L.CONTACT
        rest = L.judge(human, human.rig.rest, layout)
        assert not rest.success and not rest.touching.all()


def test_other_hands_get_known_grips():
    for kind in ("alien", "witch"):
        hand = hands.make_hand(kind)
        grip = L.known_grip(hand, "cylinder")
        assert grip.usable
        layout = L.make_layout(grip, L.BINS[1], seed=2)
        assert L.judge(hand, layout.reference, layout).success


def test_hand_turn_and_edit_verdict(human, cylinder):
    layout = L.make_layout(cylinder, L.BINS[0], seed=0)
    theta = layout.reference
    G = np.eye(4)
    G[:3, :3] = axis_angle_to_matrix([np.radians(40.0), 1.0, -2.0, 0.5])
    G[:3, 3] = [0.03, -0.01, 0.02]
    moved = L.carried(human.rig, theta, G)
    assert np.allclose(human.rig.pose_matrices(moved)[0], G @ human.rig.pose_matrices(theta)[0], atol=1e-12)
    assert np.array_equal(moved[6:], theta[6:])
    assert human.rig.deform_bones[layout.palm] == "hand" == human.rig.deform_bones[L.palm_deformer(human)]
    assert np.isclose(L.hand_turn(human, theta, moved, layout.palm), 40.0, atol=1e-9)
    assert np.isclose(L.hand_turn(human, moved, moved), 0.0, atol=1e-6)
    before = L.judge(human, theta, layout)
    assert before.touching.all()
    after = L.Verdict(moved, before.contact, before.reach, 0.0, before.touching, True)
    turned = L.judge_edit(human, before, after)
    assert np.isclose(turned.turn, 40.0) and turned.dropped == () and turned.flip  # 40° > 30°
    dropped = before.touching.copy()
    dropped[0] = False
    kept = L.judge_edit(human, before, L.Verdict(theta, before.contact, before.reach, 0.0, dropped, False))
    assert kept.turn < 1e-6 and kept.dropped == (0,) and kept.flip
    same = L.judge_edit(human, before, before)
    assert not same.flip and same.dropped == ()


def test_on_hand_moves_the_layout_with_the_skin(human, cylinder):
    layout = L.make_layout(cylinder, L.BINS[1], seed=4)
    M = np.eye(4)
    M[:3, :3] = axis_angle_to_matrix([1.1, 0.2, 1.0, -0.3])
    M[:3, 3] = [0.3, -0.2, 1.0]
    skin = SkinnedMesh(TriMesh(human.mesh.vertices @ M[:3, :3].T + M[:3, 3], human.mesh.faces), human.rig,
                       human.weights)  # fmt: skip
    there = L.on_hand(layout, skin)
    assert there.hand is skin and there.reference is None and there.palm == layout.palm
    assert np.allclose(there.positions, layout.positions @ M[:3, :3].T + M[:3, 3], atol=1e-12)
    assert np.allclose(there.normals, layout.normals @ M[:3, :3].T, atol=1e-12)
    assert np.isclose(there.angle, layout.angle) and np.isclose(there.shift, layout.shift)
    bent = human.mesh.vertices.copy()
    bent[0] += 0.01
    with pytest.raises(SolverError, match="moved rigidly"):
        L.on_hand(layout, SkinnedMesh(TriMesh(bent, human.mesh.faces), human.rig, human.weights))


def test_bad_input_is_refused(human, cylinder):
    with pytest.raises(SolverError, match="unknown object"):
        L.known_grip(human, "teapot")
    with pytest.raises(SolverError, match="Hand"):
        L.known_grip(SkinnedMesh(human.mesh, human.rig, human.weights), "box")
    with pytest.raises(SolverError, match=r"a bin of turn .* 0 <= low <= high <= 180"):
        L.make_layout(cylinder, (100.0, 45.0))
    with pytest.raises(SolverError, match=r"the slide .* 0 <= low"):
        L.make_layout(cylinder, slide=(-0.001, 0.002))
    few = L.Grip(human, "box", cylinder.object, cylinder.sdf, cylinder.theta, ("index_3",),
                 cylinder.points[[0]], np.zeros(1, np.int64))  # fmt: skip
    with pytest.raises(SolverError, match="needs 2"):
        L.make_layout(few)
    layout = L.make_layout(cylinder)
    with pytest.raises(SolverError, match="no pad 'palm'"):
        L.turned(layout, "palm", 10.0)
    with pytest.raises(SolverError, match="out of range"):
        L.turned(layout, len(layout.pads), 10.0)
    with pytest.raises(SolverError, match="per_bin"):
        bench.run(per_bin=0)
    with pytest.raises(SolverError, match="fingers"):
        bench.run(kinds=("tentacle",))


def test_quick_benchmark_run():
    """The smallest run solves one layout from rest, edits it, and tabulates a bin row and an edit row."""
    lines = []
    rows = bench.run(progress=lines.append, **bench.QUICK)
    assert [r.what for r in rows] == ["turn 0-45°", "edit: one pad turned 25°"]
    first, edit = rows
    assert first.layouts == 1 and first.hand == "alien" and 0 <= first.success <= 1
    assert first.seconds > 0 and first.evaluations >= 1 and first.slowest == first.seconds
    assert edit.layouts == first.edits and edit.flips == first.flips
    assert len(lines) == 2 and lines[1].startswith("alien cylinder turned")
    table = bench.format_table(rows)
    assert table.count("\n") == 2 and "alien" in table
