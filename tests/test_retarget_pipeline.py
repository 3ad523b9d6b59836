"""The whole retarget (solver.retarget.pipeline, §3) on synthetic motions with ground truth: the issue's
"Tests and evidence" (§4.2-4.7 of the paper).

Every figure is printed (``pytest -s`` shows them). The motions are short (48 frames, 5 s) so the file
stays within its budget; the bars are the issue's (median contact distance during contact frames
≤ 1.5 % of the target hand's length) and the regression bounds are the measured figures with a margin.
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from geodesics import TriMesh
from solver.errors import SolverError
from solver.hands import make_hand
from solver.retarget import annotate, synthetic, transfer
from solver.retarget.frames import HandSpec, RetargetWeights
from solver.retarget.pipeline import RetargetOptions, retarget
from solver.sdf import MeshSDF

FRAMES, FPS = 48, 9.6  # 4.9 s: every phase of the synthetic manipulation, a few frames each
# Hand contact samples per cm²: about 1,500 contacts per touching frame, the mean of the paper's task
# suite (its Table 4: 416-4,766, mean 1,523) and the benchmark's; the 19 x 60 marker points weigh against
# them as in the paper's prosthesis hand (its Appendix C).
DENSITY = 110.0
WORKERS = 2
BAR = 0.015  # of the target hand's length (the issue)
NO_METRICS = RetargetOptions(intersections=False)

# Target hands of §4.4: (kind, scale) -> the regression bound on the median contact distance (mm) and
# whether the bar is met. Measured on this file's motion: alien 2.35 mm (bar 3.13), witch 4.84 mm
# (bar 3.54), child 2.39 mm (bar 2.10), large 1.97 mm (bar 3.49). The witch and the child cannot meet the
# bar unless the markers and the prior are all but switched off: see
# test_other_hands_against_the_contacts_only_floor.
HANDS = {
    ("alien", 1.0): (3.0, True),
    ("witch", 1.0): (5.5, False),
    ("human", 0.75): (2.8, False),
    ("human", 1.25): (2.5, True),
}
#: Per-frame estimates only, without the marker, normal and prior terms: the floor of the contact metric.
CONTACTS_ONLY = RetargetOptions(RetargetWeights(m=0.0, cn=0.0, j=0.0), refine=False, intersections=False)


def _median_contact(distance) -> float:
    """Median of the per-frame mean contact distance over the frames with contacts, metres."""
    d = np.asarray(distance)
    d = d[np.isfinite(d)]
    assert d.size > 0, "no contact frames"
    return float(np.median(d))


def _root_errors(theta, truth) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame root location error (m) and root rotation error (degrees) between two DOF curves.

    The root's world transform is ``matrix_local @ T(loc) @ R(euler XYZ)`` with a rigid rest matrix, so
    both errors are independent of it."""
    loc = np.linalg.norm(theta[:, :3] - truth[:, :3], axis=1)
    Ra = Rotation.from_euler("xyz", theta[:, 3:6])
    Rb = Rotation.from_euler("xyz", truth[:, 3:6])
    return loc, np.degrees((Ra.inv() * Rb).magnitude())


def _palm_errors(theta, truth) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame error of the palm's world frame (the human rig's ``hand`` bone: location in metres,
    rotation in degrees). The rig's root is the forearm, which nothing but the wrist constrains, so its
    DOFs trade off against the wrist's; the palm's frame does not."""
    rig = make_hand("human").rig
    b = rig.bone_index("hand")
    A = np.stack([rig.pose_matrices(t)[b] for t in theta])
    B = np.stack([rig.pose_matrices(t)[b] for t in truth])
    loc = np.linalg.norm(A[:, :3, 3] - B[:, :3, 3], axis=1)
    R = np.einsum("fji,fjk->fik", A[:, :3, :3], B[:, :3, :3])
    cos = np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1.0, 1.0)
    return loc, np.degrees(np.arccos(cos))


def _vertex_error(a, b) -> np.ndarray:
    """Per-frame mean distance between corresponding vertices of two motions of one mesh, metres."""
    return np.linalg.norm(np.asarray(a) - np.asarray(b), axis=2).mean(axis=1)


def _finger_errors(theta, truth) -> np.ndarray:
    """Absolute errors of every finger DOF sample (all bones past the forearm root and the wrist),
    degrees."""
    return np.degrees(np.abs(theta[:, 9:] - truth[:, 9:])).ravel()


def _errors_against(r, source) -> tuple:
    """A retarget onto the human hand against the source motion's ground truth: (finger DOF errors,
    root location and rotation errors, palm frame location and rotation errors, mean vertex errors,
    median contact distance), as the functions above."""
    truth = source.source_theta
    return (
        _finger_errors(r.theta, truth),
        *_root_errors(r.theta, truth),
        *_palm_errors(r.theta, truth),
        _vertex_error(r.motion.hand_vertices, source.hand_vertices),
        _median_contact(r.contact_distance),
    )


def _root_jumps(theta) -> tuple[np.ndarray, np.ndarray]:
    """Frame-to-frame root location (m) and rotation (degrees) steps."""
    loc = np.linalg.norm(np.diff(theta[:, :3], axis=0), axis=1)
    R = Rotation.from_euler("xyz", theta[:, 3:6])
    return loc, np.degrees((R[:-1].inv() * R[1:]).magnitude())


# ------------------------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def source():
    return synthetic.generate("cylinder", frames=FRAMES, fps=FPS, seed=0, density=DENSITY)


@pytest.fixture(scope="module")
def same_hand_folder(tmp_path_factory):
    return tmp_path_factory.mktemp("retarget-same-hand")


@pytest.fixture(scope="module")
def same_hand(source, same_hand_folder):
    ann = annotate.default_annotation(make_hand("human"), make_hand("human"))
    return retarget(source, HandSpec("human", 1.0), ann, NO_METRICS, folder=same_hand_folder, workers=WORKERS)


@pytest.fixture(scope="module")
def targets(source):
    """Retargets of the source to other hands, each made on first use: ``targets(kind, scale, options)``
    (the cyclic test shares the witch, the floor and ablation tests their hands)."""
    cache = {}

    def get(kind, scale, options=NO_METRICS):
        key = kind, scale, options
        if key not in cache:
            ann = annotate.default_annotation(make_hand("human"), make_hand(kind, scale))
            cache[key] = retarget(source, HandSpec(kind, scale), ann, options, workers=WORKERS)
        return cache[key]

    return get


# ------------------------------------------------------------------------------------------ same hand


def test_same_hand_reproduces_the_source(source, same_hand):
    r = same_hand
    length = make_hand("human").length
    fingers, loc, rot, palm_loc, palm_rot, vertices, contact = _errors_against(r, source)
    print(
        f"\nsame hand: finger DOF error median {np.median(fingers):.3f}°"
        f" p95 {np.percentile(fingers, 95):.3f}° max {fingers.max():.2f}°;"
        f" root (forearm) location error median {np.median(loc) * 1e3:.2f} mm max {loc.max() * 1e3:.2f} mm,"
        f" rotation error median {np.median(rot):.3f}° max {rot.max():.2f}°;"
        f" palm frame location error median {np.median(palm_loc) * 1e3:.2f} mm"
        f" max {palm_loc.max() * 1e3:.2f} mm, rotation median {np.median(palm_rot):.3f}°"
        f" max {palm_rot.max():.2f}°; mean vertex error median {np.median(vertices) * 1e3:.3f} mm"
        f" max {vertices.max() * 1e3:.3f} mm; median contact distance {contact * 1e3:.3f} mm"
        f" (bar {BAR * length * 1e3:.2f} mm) over {np.isfinite(r.contact_distance).sum()} contact frames;"
        f" {r.summary()}"
    )
    assert r.theta.shape == source.source_theta.shape
    assert np.median(fingers) < 0.5  # measured 0.27°
    assert np.percentile(fingers, 95) < 3.5  # measured 2.6°
    assert np.median(loc) < 0.005  # measured 3.1 mm
    assert np.median(rot) < 5.0  # measured 3.6°: the forearm trades off against the wrist
    assert np.median(palm_loc) < 0.002  # measured 1.3 mm
    assert np.median(palm_rot) < 1.5  # measured 0.80°
    assert np.median(vertices) < 0.001  # measured 0.74 mm
    assert contact <= BAR * length  # measured 0.71 mm vs 2.79 mm
    # The result is a motion of the target hand posed by its own curves.
    assert np.array_equal(r.motion.source_theta, r.theta)
    assert r.motion.hand_vertices.shape == source.hand_vertices.shape


# ---------------------------------------------------------------------------------- other hands (§4.4)


def _hand_figures(r, kind, scale):
    length = make_hand(kind, scale).length
    contact = _median_contact(r.contact_distance)
    estimate = _median_contact(r.estimate_contact_distance)
    print(
        f"\n{kind} x{scale}: median contact distance {contact * 1e3:.3f} mm (per-frame estimate"
        f" {estimate * 1e3:.3f} mm), bar 1.5% of {length * 1e3:.1f} mm = {BAR * length * 1e3:.3f} mm;"
        f" marker {np.nanmedian(r.marker_distance) * 1e3:.3f} mm; {r.seconds}"
    )
    return contact, length


@pytest.mark.slow
@pytest.mark.parametrize(("kind", "scale"), list(HANDS))
def test_other_hands_contact_distance(targets, kind, scale):
    bound, meets = HANDS[kind, scale]
    contact, length = _hand_figures(targets(kind, scale), kind, scale)
    if meets:
        assert contact <= BAR * length
    if bound is not None:
        assert contact <= bound * 1e-3  # regression bound on the measured figure


@pytest.mark.slow
@pytest.mark.parametrize(("kind", "scale"), [k for k, (_, meets) in HANDS.items() if not meets])
@pytest.mark.xfail(
    strict=True,
    raises=AssertionError,
    reason="measured above the issue's bar (witch 4.84 mm vs 3.54, child 2.38 vs 2.10): the bar lies at the "
    "contacts-only floor of the transferred contacts (test_other_hands_against_the_contacts_only_floor)",
)
def test_other_hands_meet_the_bar(targets, kind, scale):
    contact, length = _hand_figures(targets(kind, scale), kind, scale)
    assert contact <= BAR * length


@pytest.mark.slow
@pytest.mark.parametrize(("kind", "scale"), list(HANDS))
def test_other_hands_against_the_contacts_only_floor(targets, kind, scale):
    """The per-frame estimate against the best any pose can do with the transferred contacts: every frame
    solved for its contacts alone (λm = λcn = λj = 0), which minimizes this very metric (the sum of the
    contact distances, Eq. 5's Γ_CD; the table still keeps the hand out). On a grasp frame that minimum
    was found to the micrometre alike from the full estimate, from the root estimate with the fingers at
    rest and from the source's own pose, by L-BFGS and by SLSQP.

    The paper's weights stay within a third of it on every hand. On the witch and the child the floor
    itself lies at the issue's bar, so only weights that all but switch off the markers and the prior
    could meet it (the contacts-only poses miss the witch's markers by 27.6 mm against 10.9 mm): the
    witch's contacts are stretched 1.5x along its fingers (λ_A = 1.51, the paper's Table 3 has 1.55) and
    the child's shrunk 0.75x (§4.4 re-uses the contacts), while their object partners keep the source
    hand's spacing."""
    bar = BAR * make_hand(kind, scale).length
    estimate = _median_contact(targets(kind, scale).estimate_contact_distance)
    floor = _median_contact(targets(kind, scale, CONTACTS_ONLY).estimate_contact_distance)
    print(
        f"\n{kind} x{scale}: per-frame estimate {estimate * 1e3:.3f} mm, contacts-only floor"
        f" {floor * 1e3:.3f} mm (x{estimate / floor:.2f}), bar {bar * 1e3:.3f} mm (floor at"
        f" {floor / bar:.0%} of it)"
    )
    assert floor < estimate < 1.4 * floor  # measured x1.19 (large) to x1.27 (witch)
    if not HANDS[kind, scale][1]:
        assert floor > 0.9 * bar  # measured 108 % (witch), 95 % (child)


# -------------------------------------------------------------------------------------- cyclic (§4.5)


@pytest.mark.slow
def test_cyclic_human_witch_human(source, targets):
    witch = targets("witch", 1.0)
    K = len(source.hand_contacts)
    original = transfer.TransferredContacts(
        hand_contacts=source.hand_contacts, object_contacts=source.object_contacts, kept=np.ones(K, bool)
    )
    ann = annotate.default_annotation(make_hand("witch"), make_hand("human"))
    back = retarget(witch.motion, HandSpec("human", 1.0), ann, NO_METRICS, workers=WORKERS, contacts=original)
    length = make_hand("human").length
    fingers, loc, rot, palm_loc, palm_rot, vertices, contact = _errors_against(back, source)
    print(
        f"\ncyclic human→witch→human: finger DOF difference median {np.median(fingers):.3f}°"
        f" p95 {np.percentile(fingers, 95):.3f}° max {fingers.max():.2f}°; root (forearm) location median"
        f" {np.median(loc) * 1e3:.2f} mm max {loc.max() * 1e3:.2f} mm ({np.median(loc) / length:.2%} of the"
        f" hand), rotation median {np.median(rot):.3f}° max {rot.max():.2f}°; palm frame location median"
        f" {np.median(palm_loc) * 1e3:.2f} mm max {palm_loc.max() * 1e3:.2f} mm, rotation median"
        f" {np.median(palm_rot):.3f}° max {palm_rot.max():.2f}°; mean vertex error median"
        f" {np.median(vertices) * 1e3:.2f} mm; median contact distance {contact * 1e3:.3f} mm"
    )
    assert np.median(palm_loc) < 0.045 * length  # measured 2.0 mm = 1.1 %
    assert np.median(palm_rot) < 8.0  # measured 3.5°
    # The root aligns in every frame: no flips (the final curves once turned 150° where an unwrapped
    # root angle passed the rig's 2π bound and was clipped instead of wrapped back).
    assert palm_loc.max() < 0.06 * length and palm_rot.max() < 15.0  # measured 5.2 mm, 8.0°
    # The forearm (the root) trades off against the wrist (see _palm_errors), so its figures move with
    # the witch's default curves where the palm frame's hardly do: the witch's thumb curve is laid out
    # from its second sideways nudge or its third depending on which face a closest-point tie on an edge
    # falls to (12.9 mm and 12.2° with the other face, the palm frame then 2.4 mm and 3.6°).
    assert np.median(loc) < 0.10 * length  # measured 16.6 mm = 8.9 %
    assert np.median(rot) < 18.0  # measured 15.3°
    assert np.median(fingers) < 6.0  # measured 3.0°
    assert contact <= BAR * length  # measured 0.69 mm vs 2.79 mm


# ------------------------------------------------------------------------------------ ablations (§4.7)


#: The no-contact ablation (§4.7: λc = 0), on per-frame estimates as the paper examines it.
NO_CONTACTS = RetargetOptions(RetargetWeights(c=0.0), refine=False, intersections=False)


def _ablation(targets, kind, scale) -> tuple[float, float]:
    """Median per-frame estimate contact distances (m) on a hand: without the contact term, with it."""
    default = _median_contact(targets(kind, scale).estimate_contact_distance)
    ablated = _median_contact(targets(kind, scale, NO_CONTACTS).estimate_contact_distance)
    print(
        f"\nno-contact ablation, {kind} x{scale} (per-frame estimates): median contact distance"
        f" {ablated * 1e3:.3f} mm vs {default * 1e3:.3f} mm with contacts (x{ablated / default:.2f})"
    )
    return ablated, default


@pytest.mark.slow
def test_ablation_without_contacts(targets):
    """§4.7 ablates the contacts on its alternate human hand; ours is the human hand at 1.25x (on the
    source's own hand the 1:1 area markers alone nearly reproduce it: measured 1.16 mm without contacts
    vs 0.71 mm with). Without contacts the hand fails to conform to the object, and the paper notes the
    failure is compounded on less humanlike hands: the alien's."""
    ablated, default = _ablation(targets, "human", 1.25)
    assert ablated > 2.0 * default  # measured 4.66 mm vs 1.97 mm (x2.37)
    alien_ablated, alien_default = _ablation(targets, "alien", 1.0)
    assert alien_ablated / alien_default > ablated / default  # measured x6.6


@pytest.mark.slow
def test_ablation_without_root_pass(source, same_hand):
    ann = annotate.default_annotation(make_hand("human"), make_hand("human"))
    options = RetargetOptions(root_pass=False, refine=False, intersections=False)
    r = retarget(source, HandSpec("human", 1.0), ann, options, workers=WORKERS)
    truth = source.source_theta
    figures = {}
    runs = (("root pass", same_hand), ("no root pass", r))
    for name, run in runs:
        loc, rot = _root_errors(run.estimate, truth)
        jl, jr = _root_jumps(run.estimate)
        figures[name] = (loc, rot, jl, jr)
        contact = _median_contact(run.estimate_contact_distance)
        print(
            f"\n{name} (per-frame estimates): root location error median {np.median(loc) * 1e3:.2f} mm"
            f" max {loc.max() * 1e3:.2f} mm; rotation error median {np.median(rot):.3f}°"
            f" max {rot.max():.2f}°; frame-to-frame root jumps max {jl.max() * 1e3:.2f} mm /"
            f" {jr.max():.2f}°; median contact distance {contact * 1e3:.3f} mm;"
            f" finger DOF error median {np.median(_finger_errors(run.estimate, truth)):.3f}°"
        )
    jl, jr = _root_jumps(truth)
    print(f"ground truth frame-to-frame root jumps max {jl.max() * 1e3:.2f} mm / {jr.max():.2f}°")
    with_, without = figures["root pass"], figures["no root pass"]
    # Measured: max root location error 172 mm / rotation 126° without the root pass, 3.4 mm / 3.9° with.
    assert with_[0].max() < 0.005 and with_[1].max() < 5.0
    assert without[0].max() > 0.03 and without[1].max() > 20.0
    assert without[2].max() > with_[2].max() and without[3].max() > with_[3].max()


# ------------------------------------------------------------------------------------ bimanual (§4.3)


@pytest.fixture(scope="module")
def bimanual():
    """Both hands of a box manipulation retargeted, each on its own, and superposed (§4.3)."""
    right, left = synthetic.bimanual("box", frames=FRAMES, fps=FPS, seed=0, density=DENSITY)
    # Onto the human hands (a larger pair would overlap where the source hands nearly touch: §4.3 covers
    # hands that interact only with the object).
    human, human_left = make_hand("human"), synthetic.source_hand("human-left")
    r_right = retarget(
        right, HandSpec("human"), annotate.default_annotation(human, human), NO_METRICS, workers=WORKERS
    )
    ann_left = annotate.default_annotation(human_left, human_left)
    r_left = retarget(left, HandSpec("human-left"), ann_left, NO_METRICS, workers=WORKERS)
    bar = BAR * human.length
    cr, cl = _median_contact(r_right.contact_distance), _median_contact(r_left.contact_distance)
    # The two posed hands against each other: nearest vertices, and the deepest vertex of one inside the
    # other wherever they come within 5 mm.
    gap = np.empty(FRAMES)
    depth = np.zeros(FRAMES)
    faces_r, faces_l = r_right.motion.hand_mesh.faces, r_left.motion.hand_mesh.faces
    for f in range(FRAMES):
        Vr, Vl = r_right.motion.hand_vertices[f], r_left.motion.hand_vertices[f]
        gap[f] = cKDTree(Vr).query(Vl)[0].min()
        if gap[f] < 0.005:
            d1 = MeshSDF(TriMesh(Vr, faces_r))(Vl, max_distance=0.0)
            d2 = MeshSDF(TriMesh(Vl, faces_l))(Vr, max_distance=0.0)
            depth[f] = max(0.0, -float(min(d1.min(), d2.min())))
    src_gap = np.array(
        [cKDTree(right.hand_vertices[f]).query(left.hand_vertices[f])[0].min() for f in range(FRAMES)]
    )
    print(
        f"\nbimanual box, both hands: median contact distance right {cr * 1e3:.3f} mm, left {cl * 1e3:.3f} mm"
        f" (bar {bar * 1e3:.3f} mm); nearest vertices of the two hands min {gap.min() * 1e3:.2f} mm"
        f" (source {src_gap.min() * 1e3:.2f} mm); deepest inter-hand penetration {depth.max() * 1e3:.3f} mm"
        f" in {np.count_nonzero(depth)} frames"
    )
    return r_right, r_left, left, cr, cl, bar, depth


@pytest.mark.slow
def test_bimanual_hands_superpose_without_meeting(bimanual):
    r_right, r_left, left, cr, cl, _, depth = bimanual
    assert r_left.theta.shape == left.source_theta.shape
    assert np.isfinite(r_right.theta).all() and np.isfinite(r_left.theta).all()
    assert np.isfinite([cr, cl]).all()
    assert depth.max() < 0.001  # the source hands come within 1.01 mm of each other


@pytest.mark.slow
def test_bimanual_hands_meet_their_contacts_alike(bimanual):
    _, _, _, cr, cl, bar, _ = bimanual
    assert cr <= bar and cl <= bar
    assert abs(cr - cl) < 0.1 * bar  # mirror images of one manipulation, solved independently


# -------------------------------------------------------------------------------------------- resume


def test_resume_and_foreign_folder(source, same_hand, same_hand_folder):
    full = same_hand_folder / "full"
    files = sorted(full.glob("[0-9]*.npz"))
    assert len(files) == FRAMES
    for p in files[3:48:15]:
        p.unlink()
    solved = []
    ann = annotate.default_annotation(make_hand("human"), make_hand("human"))
    again = retarget(
        source, HandSpec("human", 1.0), ann, NO_METRICS, folder=same_hand_folder, workers=WORKERS,
        progress=lambda stage, done, total: solved.append((stage, done, total)),
    )  # fmt: skip
    print(f"\nresume: {again.seconds}; iterations {again.iterations} vs {same_hand.iterations}")
    assert len(sorted(full.glob("[0-9]*.npz"))) == FRAMES
    # Only the deleted frames were solved again: each stage's first report counts the stored frames.
    first = {}
    for stage, done, total in solved:
        first.setdefault(stage, (done, total))
    assert first["root"] == (FRAMES, FRAMES)
    assert first["full"] == (FRAMES - 3, FRAMES)
    np.testing.assert_array_equal(again.estimate, same_hand.estimate)
    np.testing.assert_array_equal(again.theta, same_hand.theta)
    np.testing.assert_array_equal(again.contact_distance, same_hand.contact_distance)
    other = dataclasses.replace(NO_METRICS, weights=RetargetWeights(j=20.0))
    with pytest.raises(SolverError, match="another run"):
        retarget(source, HandSpec("human", 1.0), ann, other, folder=same_hand_folder, workers=WORKERS)


# ------------------------------------------------------------------------------------ short, fast motions


@pytest.mark.slow
def test_a_whole_manipulation_in_60_frames_ends_soon_and_never_silently_misses():
    """The issue's 0.5 s grasp-and-lift (60 frames at 120 fps) onto the witch: six control points (the
    paper's 10 per second) put the contacts 80 mm off where the frames reached 7 mm, and refinement ran
    its 20 rounds for nothing. Now rounds that stop helping end it, the spline gets the control points
    it needs, and what still misses says why."""
    from solver.retarget.refine import PATIENCE

    motion = synthetic.generate("mug", frames=60, seed=0)
    ann = annotate.default_annotation(make_hand("human"), make_hand("witch"))
    steps = []
    r = retarget(
        motion, HandSpec("witch"), ann, NO_METRICS, workers=WORKERS,
        progress=lambda stage, done, total: steps.append((stage, done, total)),
    )  # fmt: skip
    log, summary = r.refine_log, r.summary()
    print(summary["refinement"], summary["spline_control_points"], summary["warnings"])
    assert log.converged or log.stalled
    assert log.iterations <= 2 * PATIENCE < 20
    final, estimate = summary["median_contact_distance_mm"], summary["median_estimate_contact_distance_mm"]
    assert final <= 1.5 * estimate or summary["warnings"]
    assert summary["spline_control_points"] > summary["spline_default_control_points"] == 6
    # One bar over the whole refinement: its count never goes back, and it ends full.
    refine = [(done, total) for stage, done, total in steps if stage == "refine"]
    assert all(b[0] >= a[0] for a, b in itertools.pairwise(refine))
    assert refine[-1][0] == refine[-1][1] == log.resolves
