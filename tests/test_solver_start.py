"""The solve a person's layout needs: the trust region on the energy as squares (its compressed system is
the full one), the narrow band that skips skin far from the object (the same penalty), and the global
start that reaches a grasp the hand must travel and turn to (where a local solve from rest does not), a
small edit that stays near, and the patches a pose leaves unreached, named."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from geodesics import SurfacePoints, TriMesh
from solver import ContactIK, MeshSDF, SolverError, hands, objects, start
from solver.ik import PRESS_DEPTH, PRESS_FACTOR
from solver.layouts import BINS, OBJECTS, judge, judge_edit, known_grip, make_layout, turned
from solver.least_squares import compressed
from solver.sdf import NarrowBand


def test_the_compressed_system_has_the_full_systems_cost_gradient_and_model():
    rng = np.random.default_rng(0)
    J = rng.normal(size=(300, 12))
    J[:, 5] = 0.0  # a variable nothing depends on
    J[150:] = 0.0  # rows that are all zero, as a skin far from the object gives
    r = rng.normal(size=300)
    rc, Jc = compressed(r, J)
    assert rc.shape == (13,) and Jc.shape == (13, 12)
    assert rc @ rc == pytest.approx(r @ r, rel=1e-12)
    np.testing.assert_allclose(Jc.T @ rc, J.T @ r, atol=1e-10)
    for _ in range(3):
        step = rng.normal(size=12)
        model, full = rc + Jc @ step, r + J @ step
        assert model @ model == pytest.approx(full @ full, rel=1e-10)


def test_the_narrow_band_gives_the_bands_penetration_without_querying_far_skin():
    """Moving skin: inside within the band the distances and gradients are the solid's own, elsewhere
    (outside, or deeper than the band) positive, so the penetration a penalty sees is exactly the skin
    within the band inside; points outside by more than they move, or far inside, are not queried
    again."""
    hand = hands.make_hand("human")
    rng = np.random.default_rng(7)
    theta = rng.normal(size=hand.rig.n_dofs) * np.where(hand.rig.is_rotation, 0.2, 0.01)
    V = hand.posed_vertices(theta)
    sphere = objects.sphere(0.05)
    solid = MeshSDF(TriMesh(sphere.vertices + V.mean(0), sphere.faces))
    band = 0.006
    queried = []

    class Counting:
        def evaluate(self, x, b):
            queried.append(len(x))
            return solid.evaluate(x, b)

    tracked = NarrowBand(Counting(), band)
    for step in range(5):
        X = V + rng.normal(size=V.shape) * 2e-4 * step
        exact = solid(X)
        signed, gradient = tracked.evaluate(X)
        inside = (exact < 0) & (exact >= -band)
        np.testing.assert_allclose(signed[inside], exact[inside], rtol=0, atol=1e-15)
        np.testing.assert_allclose(gradient[inside], solid.evaluate(X[inside])[1], rtol=0, atol=1e-12)
        assert np.all(signed[~inside] > 0)
        assert np.all(gradient[exact < -band] == 0)
    assert queried[0] == len(V) and max(queried[1:]) < len(V) / 2


def test_the_narrow_band_queries_skin_resting_just_off_the_surface_only_once_it_could_be_inside():
    """Points 1-5 mm outside a ball (within the 6 mm band, inside its bounding box, so that each is
    found exactly), then each moved 1.5 mm: those found farther off than that are provably still outside
    and not queried; the others are."""
    ball = MeshSDF(objects.sphere(0.05))
    rng = np.random.default_rng(2)
    directions = rng.normal(size=(600, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    directions = directions[np.abs(directions).max(axis=1) < 0.88][:200]  # inside the ball's box
    X = directions * rng.uniform(0.051, 0.055, 200)[:, None]
    queried = []

    class Counting:
        def evaluate(self, x, b):
            queried.append(len(x))
            return ball.evaluate(x, b)

    tracked = NarrowBand(Counting(), 0.006)
    tracked.evaluate(X)
    off = ball(X)
    move = rng.normal(size=(200, 3))
    moved = X + 0.0015 * move / np.linalg.norm(move, axis=1)[:, None]
    signed, _ = tracked.evaluate(moved)
    assert np.all(off > 0) and queried == [200, np.sum(off <= 0.0015)]
    far, exact = off > 0.0015, ball(moved)
    assert np.all(signed[far] > 0) and np.all(signed[far] <= exact[far] + 1e-12)  # a lower bound, outside
    np.testing.assert_allclose(signed[~far], exact[~far], rtol=0, atol=1e-15)


def test_an_unbounded_band_gives_exact_depths_at_any_depth_and_queries_only_what_may_be_inside():
    """Pressing's depth check: a hand's middle sunk in a ball (skin up to 18 mm deep), moved a little at a
    time. The deepest point is the solid's own at every step, deep skin included (a band would see it
    as outside), while skin found outside by more than it moved is not queried again."""
    hand = hands.make_hand("human")
    V = hand.posed_vertices(hand.rig.rest)
    ball = MeshSDF(objects.sphere(0.03))
    V = V - V.mean(0)
    queried = []

    class Counting:
        def evaluate(self, x):  # exact at every depth (an unbounded band asks for no band)
            queried.append(len(x))
            return ball.evaluate(x)

    tracked = NarrowBand(Counting(), np.inf)
    rng = np.random.default_rng(4)
    for step in range(4):
        X = V + rng.normal(size=V.shape) * 3e-4 * step
        exact = ball(X)
        signed, _ = tracked.evaluate(X)
        assert exact.min() < -0.015  # deeper than the keep-out's band (6 mm on this hand)
        inside = exact < 0
        np.testing.assert_allclose(signed[inside], exact[inside], rtol=0, atol=1e-15)
        assert np.all(signed[~inside] > 0)
    assert queried[0] == len(V) and max(queried[1:]) < len(V) / 2


def test_the_table_is_queried_only_where_the_skin_may_have_come_inside_and_the_energy_is_the_same():
    """The retargeting's table (a Box, exact at any depth) behind an unbounded band: over a solve's
    evaluations the energy and gradient are bit for bit those of the table queried at every vertex (a
    fresh solve's first evaluation), while most evaluations query a small part of the skin."""
    from solver.sdf import Box

    hand = hands.make_hand("human")
    points = SurfacePoints.concatenate(hand.contact_patches(12, seed=0).values())
    P, N = hand.posed_points(hand.rig.rest, points)
    N = -N  # the targets' outward normals face the pads
    V = hand.posed_vertices(hand.rig.rest)
    low = V[:, 2].min() + 0.002  # the table's top: 2 mm above the lowest skin
    table = Box([V[:, 0].mean(), V[:, 1].mean(), low - 0.1], [0.3, 0.3, 0.1])
    queried = []

    class Counting:
        def evaluate(self, x):
            queried.append(len(x))
            return table.evaluate(x)

    tracked = ContactIK(hand, points, P, N, obstacle=Counting())
    rng = np.random.default_rng(3)
    theta, inside = hand.rig.rest, []
    for _ in range(12):
        theta = theta + rng.normal(size=hand.rig.n_dofs) * np.where(hand.rig.is_rotation, 0.01, 0.0005)
        e, terms, g = tracked.energy_and_gradient(theta)
        fresh = ContactIK(hand, points, P, N, obstacle=table)  # its first evaluation queries every vertex
        e_exact, terms_exact, g_exact = fresh.energy_and_gradient(theta)
        assert e == e_exact and terms == terms_exact and np.array_equal(g, g_exact)
        inside.append(terms["table"] > 0)
    assert any(inside)  # some skin came inside
    assert queried[0] == len(V) and np.median(queried[1:]) < len(V) / 10


def _layout(angle_degrees: float, shift: float, seed: int = 0):
    """A grasp that exists (the fingers wrapped around a cylinder by flex-to-contact), the pads a person
    would paint on it (:func:`solver.layouts.known_grip`: the parts of the fingertips that touch), their
    closest points on the cylinder as targets, the cylinder and targets then carried away by a rigid
    motion."""
    hand = hands.make_hand("human")
    grip = known_grip(hand, "cylinder")
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    R = Rotation.from_rotvec(np.radians(angle_degrees) * axis / np.linalg.norm(axis)).as_matrix()
    t = shift * np.array([1.0, -0.5, 0.3])
    moved = TriMesh(grip.object.vertices @ R.T + t, grip.object.faces)
    solid = MeshSDF(moved)
    posed, _ = hand.posed_points(grip.theta, grip.points)
    _, targets, faces = solid.query(posed @ R.T + t)
    return hand, grip.points, targets, moved.face_normals[faces], solid, grip.patches


def _contacts_of(patches, name: str) -> slice:
    """The contacts of the patch ``name`` among ``patches`` ((name, count) in order)."""
    names = [n for n, _ in patches]
    first = sum(n for _, n in patches[: names.index(name)])
    return slice(first, first + patches[names.index(name)][1])


@pytest.fixture(scope="module")
def far():
    """The cylinder turned 140° and moved 12 cm from the open hand."""
    return _layout(140.0, 0.12)


def test_a_global_start_reaches_the_grasp_the_hand_must_travel_and_turn_to(far):
    hand, points, targets, normals, solid, patches = far
    ik = ContactIK(hand, points, targets, normals, keep_out=solid, patches=patches)
    result = ik.solve()
    assert result.start == "global" and result.status == "converged"
    assert result.unreached == ()
    on_surface = np.abs(solid(hand.posed_points(result.theta, points)[0]))
    pad = np.repeat(np.arange(len(patches)), [n for _, n in patches])
    assert max(np.median(on_surface[pad == i]) for i in range(len(patches))) < 0.002  # every pad touches
    assert -solid(hand.posed_vertices(result.theta)).min() < 0.001  # no skin a millimetre inside
    local = ContactIK(hand, points, targets, normals, keep_out=solid, patches=patches, algorithm="slsqp")
    stuck = local.solve(start="local", max_evaluations=200)  # Contact Edit's solve, from the open hand
    assert len(stuck.unreached) >= 3 and stuck.energy > 3 * result.energy


def test_an_edit_of_a_solved_layout_starts_where_the_hand_is_and_stays_near(far):
    hand, points, targets, normals, solid, patches = far
    ik = ContactIK(hand, points, targets, normals, keep_out=solid, patches=patches)
    solved = ik.solve()
    # the index pad's targets slid 4 mm along the surface's tangent, as one patch moved by hand
    moved = targets.copy()
    index = _contacts_of(patches, "index_3")
    tangent = np.cross(normals[index].mean(0), [0.0, 0.0, 1.0])
    moved[index] += 0.004 * tangent / np.linalg.norm(tangent)
    moved[index] = solid.query(moved[index])[1]
    edit = ContactIK(hand, points, moved, normals, keep_out=solid, patches=patches).solve(solved.theta)
    assert edit.start == "local" and edit.unreached == ()
    turn = Rotation.from_matrix(
        hand.rig.root_transform(edit.theta)[:3, :3] @ hand.rig.root_transform(solved.theta)[:3, :3].T
    )
    assert np.degrees(turn.magnitude()) < 10
    assert (
        ContactIK(hand, points, moved, normals, patches=patches).solve(solved.theta, start="global").start
        == "global"
    )


def test_an_edit_of_a_pressed_pose_stays_near_it():
    """The alien hand's two fingertips on a box, pressed onto their patches (a pose that is not a minimum
    of the plain energy): after one pad is turned 25°, a re-solve from there relaxes away, the palm
    turning 23° in 285 evaluations. An ``"auto"`` start near its contacts pulls towards the pose it edits
    (λk): half the turn in half the evaluations, both pads touching. (Over the benchmark's 96 alien
    layouts, and before the global start kept a root fit over a hand standing through the object, the
    plain re-solve turned the palm up to 70°.)"""
    grip = known_grip(hands.make_hand("alien"), "box")
    layout = make_layout(grip, bin=BINS[0], seed=[0, list(OBJECTS).index("box"), 0, 4])
    _, solved = _solve(layout)
    before = judge(layout.hand, solved.theta, layout)
    assert before.success
    edited = turned(layout, 0, 25.0)
    ik = ContactIK(edited.hand, edited.points, edited.positions, edited.normals, keep_out=edited.sdf,
                   patches=edited.patches)  # fmt: skip
    relaxed, edit = ik.solve(solved.theta, start="local"), ik.solve(solved.theta)
    assert edit.start == "local" and "keyed" in edit.terms and "keyed" not in relaxed.terms
    turns = [
        judge_edit(layout.hand, before, judge(layout.hand, r.theta, edited), layout.palm)
        for r in (relaxed, edit)
    ]
    assert turns[0].turn > 20 and turns[1].turn < 0.5 * turns[0].turn and not turns[1].flip
    assert edit.iterations < 0.5 * relaxed.iterations


def test_a_patch_the_hand_cannot_reach_is_named(far):
    hand, points, targets, normals, _, patches = far
    out_of_reach = targets.copy()
    thumb = _contacts_of(patches, "thumb_2")
    out_of_reach[thumb] += 0.25 * np.array([0.0, 0.0, 1.0])  # the thumb's targets 25 cm off the others
    result = ContactIK(hand, points, out_of_reach, normals, patches=patches).solve()
    assert len(result.unreached) > 1  # least squares spreads the miss over the patches
    assert result.out_of_reach == ("thumb_2",) and result.gaps["thumb_2"] > 0.02


def test_patches_and_starts_are_checked(far):
    hand, points, targets, normals, *_ = far
    with pytest.raises(SolverError, match="count its contacts"):
        ContactIK(hand, points, targets, normals, patches=[("a", 3)])
    with pytest.raises(SolverError, match="name each patch once"):
        ContactIK(hand, points, targets, normals, patches=[("a", len(points) - 1), ("a", 1)])
    ik = ContactIK(hand, points, targets, normals, algorithm="slsqp")
    with pytest.raises(SolverError, match="global start needs"):
        ik.solve(start="global")
    with pytest.raises(SolverError, match="start must be one of"):
        ik.solve(start="somewhere")
    with pytest.raises(SolverError, match="trust-region algorithm needs"):
        ContactIK(hand, points, targets, normals, algorithm="trust-region", norm="l2")


def test_a_pad_left_hovering_is_pressed_onto_its_patch():
    """Pads placed by eye (slid 2-5 mm off a grip that exists): Eq. 2's minimum leaves the thumb
    hovering, its curl costing more prior than its last millimetres of contact; pressing it brings
    every pad onto the object (the issue's judge: medians within 2 mm of the surface, no skin 1 mm in),
    and the result's energy is still that of the given weights."""
    layout = make_layout(known_grip(hands.make_hand("human"), "cylinder"), bin=BINS[0], seed=0)
    ik = ContactIK(layout.hand, layout.points, layout.positions, layout.normals, keep_out=layout.sdf,
                   patches=layout.patches)  # fmt: skip
    plain = ik.solve(press=False)
    assert "thumb_2" in plain.unreached and not judge(layout.hand, plain.theta, layout).success
    pressed = ik.solve()
    assert pressed.unreached == () and judge(layout.hand, pressed.theta, layout).success
    assert pressed.energy == pytest.approx(ik.energy(pressed.theta)[0], rel=1e-12)
    assert pressed.energy > plain.energy  # touching costs prior: Eq. 2's own minimum hovers
    assert pressed.iterations > plain.iterations


def _solve(layout, **kwargs):
    ik = ContactIK(layout.hand, layout.points, layout.positions, layout.normals, keep_out=layout.sdf,
                   patches=layout.patches)  # fmt: skip
    return ik, ik.solve(**kwargs)


@pytest.mark.parametrize(("kind", "name"), [("human", "mug"), ("witch", "mug"), ("alien", "box")])
def test_the_curled_start_curls_the_fingers_that_carry_pads(kind, name):
    """Found from the contacts alone (the DOFs that carry them along their normals), the curled start's
    joints are the procedural hands' own flexion DOFs (:meth:`Hand.flexion_dofs`) and the wrist's: every
    knuckle of a chain that carries a pad turned to close, no spread or twist."""
    hand = hands.make_hand(kind)
    layout = make_layout(known_grip(hand, name), bin=BINS[0], seed=0)
    ik = ContactIK(hand, layout.points, layout.positions, layout.normals, patches=layout.patches)
    rig = hand.rig
    fingers = np.flatnonzero((rig.dof_bone != 0) & ~rig.locked)
    curled = start._curled(ik, rig.rest, fingers, 1.0 / np.bincount(ik.patch_of)[ik.patch_of])
    moved = np.flatnonzero(curled != rig.rest)
    flexion = {int(i) for c in hand.chains for i in hand.flexion_dofs(c)}
    assert set(moved) <= flexion | {rig.rotation_dof(rig.bone_index("hand"), 0)}
    carrying = [c for c, bones in hand.chains.items() if any(rig.names[b] in layout.pads for b in bones)]
    knuckles = [int(hand.flexion_dofs(c)[0]) for c in carrying]
    assert np.all(curled[knuckles] > rig.rest[knuckles])


def test_fingers_that_wrap_a_mug_start_curled_not_through_its_wall():
    """The witch hand's long fingers around a mug turned 65° and carried 21 cm: the open hand laid onto
    the pads lies through the mug, and a finger solved from there without the solids threads its wall
    (the solve ended with the thumb pad 40 mm off and the skin 3 mm deep); from the curled start every
    pad touches."""
    grip = known_grip(hands.make_hand("witch"), "mug")
    layout = make_layout(grip, bin=BINS[1], seed=[0, list(OBJECTS).index("mug"), 1, 0])
    _, result = _solve(layout)
    assert result.start == "global" and result.unreached == ()
    assert judge(layout.hand, result.theta, layout).success


@pytest.mark.parametrize(
    ("bin_index", "most"),
    [
        pytest.param(2, 300, id="after-a-root-fit"),
        pytest.param(1, 250, id="where-it-stands-but-far"),
    ],
)
def test_the_solids_join_the_solve_once_the_hand_reaches_its_grasp(bin_index, most):
    """Five human pads around a mug, solved from rest: the hand reaches its grasp without the solids
    first (:data:`solver.start.UNSOLID_EVALUATIONS`), then the skin is pushed out.

    - Turned 130° (after a root fit): with the skin kept out from the start, the trust region crept
      along the mug's wall for 628 evaluations; now 225.
    - Carried 17 cm away and turned 65°: the hand laid onto the pads goes through the mug, so the hand
      left where it stands, its fingers solved, has the lowest energy, far as it is from its contacts.
      Solved from there with the skin kept out, it crept 422 evaluations; now 169."""
    grip = known_grip(hands.make_hand("human"), "mug")
    layout = make_layout(grip, bin=BINS[bin_index], seed=[0, list(OBJECTS).index("mug"), bin_index, 0])
    _, result = _solve(layout)
    assert result.start == "global" and result.unreached == ()
    assert judge(layout.hand, result.theta, layout).success
    assert result.iterations < most


def test_a_hand_standing_through_the_object_is_not_taken_for_its_grasp():
    """A mug carried 3 cm and turned 29° from the human hand at rest: the hand where it stands, its fingers
    solved, has its palm through the mug's wall (penetration thousands of times the rest), yet its energy
    was the lowest of the starts after their fingers' solves (which thread the wall), and a hand near its
    contacts is taken as at its grasp: the solve then crept for its 2,000 evaluations to a pose 7 mm off.
    A root fit of the open hand lies better than that, so the hand where it stands is not the start."""
    grip = known_grip(hands.make_hand("human"), "mug")
    layout = make_layout(grip, bin=BINS[0], seed=[0, list(OBJECTS).index("mug"), 0, 5])
    _, result = _solve(layout)
    assert result.start == "global" and result.iterations < 500
    assert judge(layout.hand, result.theta, layout).success


def test_pressing_does_not_push_the_skin_in():
    """Two alien fingertip pads placed by eye on a box, where they cannot lie flat on their targets:
    pressed on the last millimetres, they pushed the skin 1.4 mm into the box. A press is kept only
    while the skin stays within :data:`PRESS_DEPTH` of the surface (or no deeper than before)."""
    grip = known_grip(hands.make_hand("alien"), "box")
    layout = make_layout(grip, bin=BINS[0], seed=[0, list(OBJECTS).index("box"), 0, 2])
    ik, plain = _solve(layout, press=False)
    pressed = ik.solve()
    depth = [-layout.sdf(layout.hand.posed_vertices(r.theta)).min() for r in (plain, pressed)]
    assert pressed.iterations > plain.iterations  # it pressed
    assert depth[0] < PRESS_DEPTH * ik.unit and depth[1] <= PRESS_DEPTH * ik.unit


def test_pressing_goes_on_past_a_round_it_does_not_keep():
    """An alien fingertip pad whose targets wrap over an edge of a box (the box turned 122°): pressed at
    ten times its weight it slips from 2.54 to 2.57 mm off its targets, yet at a hundred times it comes
    to 2.1 mm and touches. A round that is not kept no longer ends pressing; the next presses harder,
    from the best pose so far, with the skin still within :data:`PRESS_DEPTH`."""
    grip = known_grip(hands.make_hand("alien"), "box")
    layout = make_layout(grip, bin=BINS[2], seed=[0, list(OBJECTS).index("box"), 2, 1])
    ik, plain = _solve(layout, press=False)
    first, _ = ik._press_round(plain, ik.contact_weights * PRESS_FACTOR, None, None, 0, 1000, 0.0)
    assert plain.unreached == ("middle_4",) and ik._standing(first) >= ik._standing(plain)
    pressed = ik.solve()
    assert pressed.unreached == () and pressed.gaps["middle_4"] < plain.gaps["middle_4"] - 0.3e-3
    assert -layout.sdf(layout.hand.posed_vertices(pressed.theta)).min() <= PRESS_DEPTH * ik.unit


def test_contact_weights_scale_their_contacts_terms_and_are_checked(far):
    hand, points, targets, normals, *_ = far
    c = np.random.default_rng(5).uniform(0.0, 4.0, len(points))
    theta = hand.rig.rest
    _, plain = ContactIK(hand, points, targets, normals).energy(theta)
    ik = ContactIK(hand, points, targets, normals, contact_weights=c)
    _, weighted = ik.energy(theta)
    posed, posed_normals = hand.posed_points(theta, points)
    d2 = np.sum((posed - targets) ** 2, axis=1) / ik.unit**2
    assert weighted["distance"] == pytest.approx(c @ d2, rel=1e-12)
    assert weighted["normal"] == pytest.approx(c @ (1 + np.sum(posed_normals * normals, axis=1)), rel=1e-12)
    assert weighted["prior"] == plain["prior"]
    for bad, match in (([1.0], "one factor per contact"), (np.full(len(points), -1.0), "not finite")):
        with pytest.raises(SolverError, match=match):
            ContactIK(hand, points, targets, normals, contact_weights=bad)
