"""An annotation drawn as patches on two hands (solver.retarget.drawn): drawn to match the built-in default
it is the default, bit for bit; λ_A and λ_S are measured where a closed form says what they are; markers
pair as the paper's kinds; what cannot be an annotation is refused naming the patch."""

import numpy as np
import pytest

from geodesics import ContactPatch, ContactSet, SurfacePoints
from solver.hands import make_hand
from solver.retarget import annotate
from solver.retarget.annotations import AnnotationError
from solver.retarget.drawn import annotation_from_patches


@pytest.fixture(scope="module")
def human():
    return make_hand("human")


@pytest.fixture(scope="module")
def alien():
    return make_hand("alien")


@pytest.fixture(scope="module")
def default(human, alien):
    return annotate.default_annotation(human, alien)


def _strip(mesh, axis, width: float) -> SurfacePoints:
    """The vertices within ``width`` of an axis' points (a strip painted along it)."""
    A = axis.points.positions(mesh)
    d = np.linalg.norm(mesh.vertices[:, None] - A[None], axis=2).min(axis=1)
    return SurfacePoints.from_vertices(mesh, np.flatnonzero(d <= width))


def _drawn(hand, markers: dict) -> ContactSet:
    """What an artist draws to match the default: a strip along each default curve, its axis the curve,
    and a patch of each marker's points (its axis is of no use to a marker)."""
    curves = annotate.hand_curves(hand)
    patches = {
        name: ContactPatch(hand.mesh, _strip(hand.mesh, axis, 0.5 * girth), axis)
        for name, (axis, girth) in curves.items()
    }
    some_axis = curves["middle"][0]
    patches.update({name: ContactPatch(hand.mesh, p, some_axis) for name, p in markers.items()})
    return ContactSet(hand.mesh, patches)


def drawn_pair(human, alien, default) -> tuple[ContactSet, ContactSet]:
    """The patches of both hands drawn to match ``default`` (its markers' points as they are)."""
    source = _drawn(human, {m.name: m.source for m in default.markers})
    target = _drawn(alien, {m.name: m.target for m in default.markers})
    return source, target


def drawn_to_match(human, alien, default):
    """The annotation read from :func:`drawn_pair` with the default's λ_S and ε_g (λ_A measured)."""
    scales = {c.name: (None, c.radial_scale) for c in default.curves if not c.dropped}
    return annotation_from_patches(
        *drawn_pair(human, alien, default),
        markers=[m.name for m in default.markers],
        scales=scales,
        threshold=default.threshold,
    )


@pytest.fixture(scope="module")
def drawn(human, alien, default):
    return drawn_pair(human, alien, default)


def test_drawn_to_match_the_default_it_is_the_default(human, alien, default):
    """Curves on the default axes (λ_A measured from them), the default's markers, its λ_S and ε_g: the
    file's content is the default's, bit for bit (the CLI reads it: test_retarget_cli)."""
    got = drawn_to_match(human, alien, default)
    assert got.to_dict() == default.to_dict()
    assert {m.kind for m in got.markers} == {"many-to-one"}
    assert [c.name for c in got.curves if c.dropped] == ["ring", "pinky"]  # the alien has three fingers


def test_the_scales_of_a_hand_drawn_again_at_another_size_are_that_size(human):
    """The same strips on the same hand at 0.75 times the size: every axis is 0.75 times as long and every
    strip 0.75 times as wide, so λ_A = λ_S = 0.75 (to the exact solver's rounding); the same spots on
    both are an area marker."""
    small = make_hand("human", 0.75)
    big_set = _drawn(human, {})
    small_set = ContactSet(
        small.mesh,
        {
            name: ContactPatch(small.mesh, p.points, annotate.hand_curves(small)[name][0])
            for name, p in big_set.patches.items()
        },
    )
    spots = big_set["index"].points  # the same skin spots on both: an area marker, row for row
    big_set = big_set.add("spots", ContactPatch(human.mesh, spots, big_set["index"].axis))
    small_set = small_set.add("spots", ContactPatch(small.mesh, spots, small_set["index"].axis))
    got = annotation_from_patches(big_set, small_set, markers=["spots"])
    assert got.markers[0].kind == "area"
    np.testing.assert_array_equal(got.markers[0].target.faces, spots.faces)
    for c in got.curves:
        assert c.axis_scale == pytest.approx(0.75, rel=1e-6), c.name
        assert c.radial_scale == pytest.approx(0.75, rel=1e-6), c.name
    assert got.threshold == pytest.approx(annotate.THRESHOLD_PER_LENGTH * 0.2038, rel=1e-3)


def test_markers_pair_as_the_papers_kinds(human, alien, drawn):
    source, target = drawn
    some_axis = source["middle"].axis
    t_axis = target["middle"].axis
    area = source["index"].points  # a painted area
    cases = {
        "as many": (area, SurfacePoints(area.faces[::-1].copy(), area.bary[::-1].copy())),
        "single": (area[[0]], SurfacePoints.from_vertices(alien.mesh, [7])),
        "many-to-one": (area[[0]], target["index"].points),
        "sizes differ": (area, target["index"].points[:5]),
    }
    src = ContactSet(
        human.mesh,
        {
            "palm": source["palm"],
            **{k: ContactPatch(human.mesh, s, some_axis) for k, (s, _) in cases.items()},
        },
    )
    tgt = ContactSet(
        alien.mesh,
        {"palm": target["palm"], **{k: ContactPatch(alien.mesh, t, t_axis) for k, (_, t) in cases.items()}},
    )
    got = {m.name: m for m in annotation_from_patches(src, tgt, markers=cases).markers}
    kinds = {n: m.kind for n, m in got.items()}
    assert kinds == {"as many": "many-to-one", "single": "single", "many-to-one": "many-to-one"} | {
        "sizes differ": "many-to-one"
    }
    # Areas of different sizes: the source point nearest the centroid, tracked by the whole target area.
    P = area.positions(human.mesh)
    nearest = np.argmin(np.linalg.norm(P - P.mean(0), axis=1))
    np.testing.assert_array_equal(got["sizes differ"].source.faces, area.faces[[nearest]])
    assert len(got["sizes differ"].target) == 5


def test_pairs_rename_and_unpaired_curves_are_dropped(drawn):
    source, target = drawn
    renamed = ContactSet(
        target.mesh, {f"t_{n}": p for n, p in target.patches.items() if n in ("index", "palm")}
    )
    got = annotation_from_patches(source, renamed, pairs={"index": "t_index", "palm": "t_palm"})
    kept = {c.name for c in got.curves if not c.dropped}
    assert kept == {"index", "palm"}
    assert len(got.curves) == len(source)


def test_what_cannot_be_an_annotation_is_refused_naming_the_patch(human, alien, drawn):
    source, target = drawn
    with pytest.raises(
        AnnotationError, match="'index' on the source is a marker but its counterpart 'thumb'"
    ):
        annotation_from_patches(source, target, markers=["index"], pairs={"index": "thumb"})
    flat = ContactSet(
        human.mesh, {"index": ContactPatch(human.mesh, source["index"].axis.points, source["index"].axis)}
    )
    with pytest.raises(AnnotationError, match="curve 'index': its patch on the source hand has no width"):
        annotation_from_patches(flat, target)
    assert annotation_from_patches(flat, target, scales={"index": (None, 1.2)}).curves[0].radial_scale == 1.2
    with pytest.raises(
        AnnotationError, match=r"no curve on the source \(index\) has a counterpart on the target"
    ):
        annotation_from_patches(flat, ContactSet(alien.mesh, {"palm": target["palm"]}))
