"""A starting annotation proposed from any skinned hand's bones (solver.retarget.propose): read from the
procedural hands' plain bones it draws the built-in finger curves exactly, whatever the bones' roll; what
it cannot tell (straight fingers, two hands) it asks for, and the answer is used."""

import numpy as np
import pytest
from scipy import sparse

from solver.hands import make_hand
from solver.retarget import annotate
from solver.retarget.annotations import AnnotationError
from solver.retarget.drawn import annotation_from_patches
from solver.retarget.propose import Skeleton, propose_patches

FINGERS = ("thumb", "index", "middle", "ring", "pinky")


def _skeleton(hand, roll: float = 0.0) -> Skeleton:
    """The hand's bones as any armature gives them, each turned by ``roll`` about its own length."""
    M = np.array(hand.rig.matrix_local)
    c, s = np.cos(roll), np.sin(roll)
    R = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])  # about y
    M[:, :3, :3] = M[:, :3, :3] @ R
    return Skeleton(hand.rig.names, hand.rig.parents, M, hand.rig.lengths, hand.weights.tocsr())


@pytest.fixture(scope="module")
def human():
    return make_hand("human")


def _assert_default_fingers(hand, proposal):
    default = annotate.hand_curves(hand)
    for name in hand.chains:
        np.testing.assert_array_equal(
            proposal.contacts[name].axis.points.faces, default[name][0].points.faces
        )
        np.testing.assert_allclose(
            proposal.contacts[name].axis.points.bary, default[name][0].points.bary, atol=1e-12
        )


@pytest.mark.parametrize("kind", ["human", "alien", "witch"])
def test_the_procedural_hands_bones_give_their_built_in_curves(kind):
    hand = make_hand(kind)
    proposal = propose_patches(hand.mesh, _skeleton(hand))
    assert proposal.wrist == "hand" and proposal.palmar == "+Z"
    assert {f: list(c) for f, c in proposal.chains.items()} == {
        f: [hand.rig.names[b] for b in hand.chains[f]] for f in FINGERS if f in hand.chains
    }
    _assert_default_fingers(hand, proposal)
    # The palm curves lie where the built-in ones do, up to the palm's side (the fingers' mean here).
    default = annotate.hand_curves(hand)
    for name in ("palm", "palm_across"):
        ends = proposal.contacts[name].axis.points.positions(hand.mesh)[[0, -1]]
        built_in = default[name][0].points.positions(hand.mesh)[[0, -1]]
        assert np.abs(ends - built_in).max() < 0.03 * hand.length, name
    markers = set(proposal.markers)
    assert markers == set(annotate.hand_markers(hand)) and markers <= set(proposal.contacts)


@pytest.mark.parametrize(("roll", "side"), [(np.pi / 2, "-X"), (-np.pi / 2, "+X"), (np.pi, "-Z")])
def test_the_palmar_side_is_found_whatever_the_bones_roll(human, roll, side):
    """Bones rolled about their length: the fingers still curl to the palm, so the side is found on the
    rolled axis and the curves are the built-in ones again."""
    proposal = propose_patches(human.mesh, _skeleton(human, roll))
    assert proposal.palmar == side
    _assert_default_fingers(human, proposal)


def test_proposals_of_two_hands_annotate_the_pair(human):
    """Proposed on both hands, the patches read as an annotation (curves paired by finger name; the
    alien's missing fingers dropped; markers many-to-one), with λ_A near the built-in one."""
    alien = make_hand("alien")
    source, target = (
        propose_patches(human.mesh, _skeleton(human)),
        propose_patches(alien.mesh, _skeleton(alien)),
    )
    got = annotation_from_patches(source.contacts, target.contacts, markers=source.markers + target.markers)
    default = {c.name: c for c in annotate.default_annotation(human, alien).curves}
    for c in got.curves:
        assert c.dropped == default[c.name].dropped, c.name
        if not c.dropped and c.name in human.chains:
            assert c.axis_scale == pytest.approx(default[c.name].axis_scale, rel=1e-9)
            assert c.radial_scale == pytest.approx(default[c.name].radial_scale, rel=0.35)
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
