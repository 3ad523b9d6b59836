"""A starting annotation proposed from any skinned hand's bones (solver.retarget.propose): read from the
procedural hands' plain bones it draws the built-in finger curves exactly, and the same whatever the
bones' roll; what it cannot tell (straight fingers, two hands) it asks for, and the answer is used."""

import numpy as np
import pytest
from scipy import sparse

from solver.hands import make_hand
from solver.retarget import annotate
from solver.retarget.annotations import AnnotationError
from solver.retarget.drawn import annotation_from_patches
from solver.retarget.propose import Skeleton, propose_patches

FINGERS = ("thumb", "index", "middle", "ring", "pinky")


def _skeleton(hand, roll=0.0) -> Skeleton:
    """The hand's bones as any armature gives them, each turned by ``roll`` (per bone, or one for all)
    about its own length."""
    M = np.array(hand.rig.matrix_local)
    roll = np.broadcast_to(roll, len(M))
    c, s, z = np.cos(roll), np.sin(roll), np.zeros(len(M))
    R = np.stack([np.stack([c, z, s], -1), np.stack([z, z + 1, z], -1), np.stack([-s, z, c], -1)], 1)
    M[:, :3, :3] = M[:, :3, :3] @ R  # about y
    return Skeleton(hand.rig.names, hand.rig.parents, M, hand.rig.lengths, hand.weights.tocsr())


@pytest.fixture(scope="module")
def human():
    return make_hand("human")


def _assert_same_fingers(a, b):
    """Two proposals' curves of the fingers but the thumb are the same (to rounding)."""
    for name in set(a.chains) - {"thumb"}:
        p, q = a.contacts[name].axis.points, b.contacts[name].axis.points
        np.testing.assert_array_equal(p.faces, q.faces, err_msg=name)
        np.testing.assert_allclose(p.bary, q.bary, atol=1e-9, err_msg=name)


#: How near (of the hand's length) a proposed curve's ends come to the built-in curve's: the built-in ones
#: end at the skin nearest a probe point, the proposed ones where a ray from the bone leaves the skin (a
#: millimetre or two apart), and the thumb's side is the bisector of its curl and the palm's side (within
#: 3° of the procedural thumbs' z; the witch's long thumb ends 12 mm from its built-in curve).
NEAR = {"thumb": 0.06}


@pytest.mark.parametrize("kind", ["human", "alien", "witch"])
def test_the_procedural_hands_bones_give_curves_near_their_built_in_ones(kind):
    hand = make_hand(kind)
    proposal = propose_patches(hand.mesh, _skeleton(hand))
    assert proposal.wrist == "hand" and proposal.palmar == "curl"
    assert {f: list(c) for f, c in proposal.chains.items()} == {
        f: [hand.rig.names[b] for b in hand.chains[f]] for f in FINGERS if f in hand.chains
    }
    for name, (axis, girth) in annotate.hand_curves(hand).items():
        ends = proposal.contacts[name].axis.points.positions(hand.mesh)[[0, -1]]
        built_in = axis.points.positions(hand.mesh)[[0, -1]]
        assert np.abs(ends - built_in).max() < NEAR.get(name, 0.025) * hand.length, name
        assert proposal.girths[name] == girth
    markers = set(proposal.markers)
    assert markers == set(annotate.hand_markers(hand)) and markers <= set(proposal.contacts)


def test_the_proposal_is_the_same_whatever_the_bones_roll(human):
    """Each finger's bones rolled about their length by their own angle (riggers roll them their own way):
    every finger still curls the same way, so the curves and markers are the same (to rounding)."""
    rng = np.random.default_rng(7)
    roll = np.zeros(len(human.rig.names))
    for chain in human.chains.values():
        roll[list(chain)] = rng.uniform(-np.pi, np.pi)
    plain, rolled = (
        propose_patches(human.mesh, _skeleton(human)),
        propose_patches(human.mesh, _skeleton(human, roll)),
    )
    for name in plain.contacts:
        a, b = plain.contacts[name], rolled.contacts[name]
        np.testing.assert_array_equal(a.axis.points.faces, b.axis.points.faces, err_msg=name)
        np.testing.assert_allclose(a.axis.points.bary, b.axis.points.bary, atol=1e-9, err_msg=name)
        np.testing.assert_array_equal(a.points.faces, b.points.faces, err_msg=name)


@pytest.mark.parametrize(
    ("roll", "side"), [(0.0, "+Z"), (np.pi / 2, "-X"), (-np.pi / 2, "+X"), (np.pi, "-Z")]
)
def test_a_palmar_side_given_is_the_bones_axis(human, roll, side):
    """Given, the side is that local axis of every finger bone: rolled bones with the axis the roll moved
    their z to give the fingers' curves found from their curl (exactly their z) again."""
    proposal = propose_patches(human.mesh, _skeleton(human, roll), palmar=side)
    assert proposal.palmar == side
    _assert_same_fingers(proposal, propose_patches(human.mesh, _skeleton(human)))


def test_proposals_of_two_hands_annotate_the_pair(human):
    """Proposed on both hands, the patches read as an annotation (curves paired by finger name; the
    alien's missing fingers dropped; markers many-to-one), λ_A near the built-in one, and from the
    girths the built-in λ_S."""
    alien = make_hand("alien")
    source, target = (
        propose_patches(human.mesh, _skeleton(human)),
        propose_patches(alien.mesh, _skeleton(alien)),
    )
    girths = {n: (None, target.girths[n] / g) for n, g in source.girths.items() if n in target.girths}
    got = annotation_from_patches(
        source.contacts, target.contacts, markers=source.markers + target.markers, scales=girths
    )
    default = {c.name: c for c in annotate.default_annotation(human, alien).curves}
    for c in got.curves:
        assert c.dropped == default[c.name].dropped, c.name
        if not c.dropped:
            assert c.axis_scale == pytest.approx(default[c.name].axis_scale, rel=0.1)
            assert c.radial_scale == pytest.approx(default[c.name].radial_scale, rel=1e-9)
    assert {m.kind for m in got.markers} == {"many-to-one"}


def test_straight_fingers_ask_for_the_palmar_side(human):
    sk = _skeleton(human)
    M = sk.matrices.copy()
    for chain in human.chains.values():  # every finger bone along its chain's first
        for b in chain[1:]:
            M[b, :3, :3] = M[chain[0], :3, :3]
    straight = Skeleton(sk.names, sk.parents, M, sk.lengths, sk.weights)
    with pytest.raises(AnnotationError, match=r"straight in the rest pose.*choose it \(\+Z, -Z, \+X, -X\)"):
        propose_patches(human.mesh, straight)
    assert propose_patches(human.mesh, straight, palmar="+Z").palmar == "+Z"
    curled_thumb = Skeleton(
        sk.names, sk.parents, np.where(_in(human, "thumb"), sk.matrices, M), sk.lengths, sk.weights
    )
    assert propose_patches(human.mesh, curled_thumb).palmar == "curl"  # the straight ones follow the thumb


def _in(hand, chain) -> np.ndarray:
    """(b, 1, 1) whether each bone is in the chain."""
    return np.isin(np.arange(len(hand.rig.names)), hand.chains[chain])[:, None, None]


def test_an_armature_with_two_hands_asks_for_the_wrist(human):
    """Two copies of the hand's bones under one root, both skinning the mesh: which is meant has to be named
    (a mesh weighted to one hand only is read without asking: the other's bones weight nothing)."""
    sk = _skeleton(human)
    b = len(sk.names)
    names = ("body", *sk.names, *(f"{n}.L" for n in sk.names))
    parents = np.concatenate(
        [[-1], np.where(sk.parents < 0, 0, sk.parents + 1), np.where(sk.parents < 0, 0, sk.parents + 1 + b)]
    )
    M = np.concatenate([sk.matrices[:1], sk.matrices, sk.matrices])
    n = human.mesh.n_vertices
    W = sparse.hstack([sparse.csr_matrix((n, 1)), 0.99 * sk.weights, 0.01 * sk.weights]).tocsr()
    both = Skeleton(names, parents, M, np.concatenate([[0.1], sk.lengths, sk.lengths]), W)
    with pytest.raises(AnnotationError, match="more than one hand"):
        propose_patches(human.mesh, both)
    assert propose_patches(human.mesh, both, wrist="hand").wrist == "hand"
    with pytest.raises(AnnotationError, match="no bone 'wrist'"):
        propose_patches(human.mesh, both, wrist="wrist")
