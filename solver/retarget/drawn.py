"""A hand-pair annotation from patches drawn on the two hands (Kinematic Motion Retargeting §3.3, Appendix B).

The paper's artist annotates a new hand with the tools Contact Edit gives for contacts: each axial curve
is a patch's axis, drawn along the palmar side of a finger or across the palm with the axis tool, and
each virtual marker is a painted patch. :func:`annotation_from_patches` reads two such sets of patches,
one per hand, into the :class:`.annotations.HandPairAnnotation` that the retargeting pipeline (and
``contact-edit retarget --annotation``) uses:

* a curve pairs with the target's curve of the same name (or the one ``pairs`` names); its landmarks are
  the source axis' points, its layout on the target starts where the target axis starts and heads its
  way; λ_A is the ratio of the two axes' lengths and λ_S the ratio of the two strips' half-widths (the
  mean distance of a patch's points from its axis), unless given. A source curve without a counterpart
  is dropped (its contacts go to the nearest remaining landmark, within ε_g);
* a marker pairs the same way. One point on each hand is a single marker. Otherwise it is the paper's
  many-to-one marker: the source's point (of an area, the one nearest its centroid) tracked by every
  point of the target's area. Only on two hands of the same mesh (a hand and its copy at another scale)
  are two areas of as many points an area marker, matched row for row: points painted on two different
  hands have no row-for-row correspondence.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np

from geodesics import ContactPatch, ContactSet

from .annotate import THRESHOLD_PER_LENGTH
from .annotate import procedural_kind as _procedural_kind
from .annotations import AnnotationError, CurveAnnotation, HandPairAnnotation, HandRef, MarkerAnnotation


def annotation_from_patches(
    source: ContactSet,
    target: ContactSet,
    markers: Iterable[str] = (),
    pairs: Mapping[str, str] | None = None,
    scales: Mapping[str, tuple[float | None, float | None]] | None = None,
    threshold: float | None = None,
) -> HandPairAnnotation:
    """The annotation of a hand pair drawn as patches on each hand.

    Parameters
    ----------
    source, target : ContactSet
        The patches drawn on the source and on the target hand (their meshes are the hands' rest meshes).
    markers : iterable of str
        The names (on either hand) of the patches that are virtual markers; every other patch is a curve.
    pairs : mapping, optional
        Source patch name -> target patch name, where they differ (default: the same name).
    scales : mapping, optional
        Source curve name -> (λ_A, λ_S); None (or a missing entry) measures that λ from the patches.
    threshold : float, optional
        ε_g; default :data:`.annotate.THRESHOLD_PER_LENGTH` times the extent of the source's curves
        (about the hand's length when they cover the fingers).

    Raises
    ------
    AnnotationError
        Naming the patch: a marker paired with a curve, a λ that cannot be measured (a strip of no
        width: paint it, or give λ_S), no curve with a counterpart.
    """
    markers, pairs, scales = set(markers), dict(pairs or {}), dict(scales or {})
    same_mesh = source.mesh.topology_hash == target.mesh.topology_hash
    curves, marker_list = [], []
    for name in source:
        other = pairs.get(name, name)
        counterpart = target.patches.get(other)
        if (name in markers) != (other in markers) and counterpart is not None:
            raise AnnotationError(
                f"'{name}' on the source is a {'marker' if name in markers else 'curve'} but its counterpart "
                f"'{other}' on the target is not: pair curves with curves and markers with markers"
            )
        patch = source[name]
        if name in markers:
            if counterpart is not None:
                marker_list.append(MarkerAnnotation(name, *_marker_points(patch, counterpart, same_mesh)))
        elif counterpart is None:
            curves.append(CurveAnnotation(name, patch.axis.points))
        else:
            axis_scale, radial_scale = scales.get(name, (None, None))
            if axis_scale is None:
                axis_scale = counterpart.axis.length / patch.axis.length
            if radial_scale is None:
                radial_scale = _ratio(_half_width(counterpart), _half_width(patch), name)
            curves.append(
                CurveAnnotation(
                    name,
                    patch.axis.points,
                    counterpart.axis.start,
                    counterpart.axis.direction,
                    float(axis_scale),
                    float(radial_scale),
                )
            )
    if not any(not c.dropped for c in curves):
        raise AnnotationError(
            f"no curve on the source ({', '.join(n for n in source if n not in markers) or 'none'}) has a "
            f"counterpart on the target ({', '.join(n for n in target if n not in markers) or 'none'}): "
            "give the curves of the two hands the same names, or pair them"
        )
    if threshold is None:
        P = np.concatenate([c.source.positions(source.mesh) for c in curves])
        threshold = THRESHOLD_PER_LENGTH * float(np.linalg.norm(P.max(0) - P.min(0)))
    return HandPairAnnotation(_ref(source), _ref(target), tuple(curves), tuple(marker_list), float(threshold))


def _ref(contacts: ContactSet) -> HandRef:
    mesh = contacts.mesh
    return HandRef.of(mesh, _procedural_kind(mesh))


def _half_width(patch: ContactPatch) -> float:
    """The mean distance of a patch's points from its axis, across it."""
    return float(np.mean(np.abs(patch.coords.imag)))


def _ratio(target: float, source: float, name: str) -> float:
    if not (source > 0 and target > 0):
        raise AnnotationError(
            f"curve '{name}': its patch on the {'source' if not source > 0 else 'target'} hand has no width "
            "across its axis, so λ_S (the girth ratio) cannot be measured: paint the strip across the "
            "finger, or give λ_S"
        )
    return target / source


def _marker_points(source: ContactPatch, target: ContactPatch, same_mesh: bool):
    s, t = len(source), len(target)
    if (s == t and same_mesh) or s == 1:
        return source.points, target.points
    P = source.positions()
    return source.points[[int(np.argmin(np.linalg.norm(P - P.mean(0), axis=1)))]], target.points
