"""A hand's retargeting annotation in the .blend: curves and markers drawn with the contact tools.

Each hand mesh keeps a second contact set beside its contacts (:mod:`..store`, layer ``ANNOTATION``): a
patch's axis is an axial curve (drawn with the Axis tool along a finger's palmar side or across the palm,
the patch painted as a strip across the finger), or the patch is a virtual marker (its entry's *Marker*
flag). Curves and markers pair between two hands by name; λ_A and λ_S are measured from the two hands'
patches unless set on the target's entry (:func:`solver.retarget.drawn.annotation_from_patches`).

:func:`propose` draws a starting annotation from the hand's armature (:mod:`solver.retarget.propose`);
:func:`hand_pair` reads two hands' annotations as the :class:`solver.retarget.HandPairAnnotation` that
Retarget uses and *Export Annotation* writes as the ``annotation.json`` the CLI reads.
"""

from __future__ import annotations

import bpy

from geodesics import TriMesh
from solver.retarget import (
    AnnotationError,
    HandPairAnnotation,
    Proposal,
    annotation_from_patches,
    propose_patches,
)

from .. import bridge, store
from ..bridge import BridgeError

LAYER = "ANNOTATION"


def has_annotation(obj: bpy.types.Object | None) -> bool:
    """Whether ``obj`` is a mesh with an annotation (none where the add-on is not registered: a script
    using :mod:`.scene` with the bare ``bpy`` module)."""
    return (
        obj is not None
        and obj.type == "MESH"
        and hasattr(obj, "contact_edit")
        and bool(store.entries(obj, LAYER))
    )


def proposal_work(hand: bpy.types.Object, wrist: str = "", palmar: str | None = None):
    """What :func:`propose` computes, as a function of plain data (for a worker thread), read now."""
    mesh = bridge.trimesh(hand)
    skeleton = bridge.hand_skeleton(hand)

    def work() -> Proposal:
        return propose_patches(mesh, skeleton, wrist or None, palmar)

    return work


def keep(hand: bpy.types.Object, proposal: Proposal) -> None:
    """Store a proposal as the hand's annotation (replacing it) and show it: the tools now edit it."""
    listed = store.entries(hand, LAYER)
    listed.clear()
    store.save(hand, proposal.contacts, layer=LAYER, markers=proposal.markers)
    for entry in listed:
        entry.girth = proposal.girths.get(entry.name, 0.0)
    hand.contact_edit.layer = LAYER


def propose(hand: bpy.types.Object, wrist: str = "", palmar: str | None = None) -> Proposal:
    """Draw a starting annotation on ``hand`` from its armature and keep it; returns what was read.

    Raises BridgeError naming what could not be read (no armature, no finger chains, straight fingers
    with no palmar side given)."""
    try:
        proposal = proposal_work(hand, wrist, palmar)()
    except AnnotationError as err:
        raise BridgeError(f"'{hand.name}': {err}", hand.name) from err
    keep(hand, proposal)
    return proposal


def hand_pair(
    source: bpy.types.Object,
    target: bpy.types.Object,
    source_mesh: TriMesh | None = None,
    target_mesh: TriMesh | None = None,
) -> HandPairAnnotation:
    """The annotation of the pair from the two hands' drawn ones: markers are the entries flagged on either
    hand; λ_A and λ_S those set (non-zero) on the target's curves, else λ_S the ratio of the two curves'
    girths where both have one, else both measured from the patches. ``source_mesh`` and ``target_mesh``,
    if given, are the hands' meshes as the retarget reads them, checked against.

    Raises BridgeError naming the hand without an annotation or what does not pair.
    """
    for role, obj in (("source", source), ("target", target)):
        if not has_annotation(obj):
            raise BridgeError(
                f"the {role} hand '{obj.name}' has no annotation: propose one (Retarget > Annotation), or "
                "draw its curves and markers with the tools while it edits its annotation",
                obj.name,
            )
    markers = {e.name for obj in (source, target) for e in store.entries(obj, LAYER) if e.marker}
    girths = {e.name: e.girth for e in store.entries(source, LAYER) if not e.marker and e.girth > 0}
    scales = {}
    for e in store.entries(target, LAYER):
        if e.marker:
            continue
        radial = e.radial_scale or (e.girth / girths[e.name] if e.girth > 0 and e.name in girths else None)
        if e.axis_scale or radial:
            scales[e.name] = (e.axis_scale or None, radial)
    try:
        annotation = annotation_from_patches(
            store.load(source, layer=LAYER), store.load(target, layer=LAYER), markers, scales=scales
        )
        if source_mesh is not None and target_mesh is not None:
            annotation.check(source_mesh, target_mesh)
    except AnnotationError as err:
        raise BridgeError(f"the annotations of '{source.name}' and '{target.name}': {err}") from err
    return annotation


def summary(annotation: HandPairAnnotation) -> str:
    """One line: what pairs and what is dropped."""
    kept = [c.name for c in annotation.curves if not c.dropped]
    dropped = [c.name for c in annotation.curves if c.dropped]
    text = f"{len(kept)} curves ({', '.join(kept)}), {len(annotation.markers)} markers"
    return text + (f"; dropped: {', '.join(dropped)}" if dropped else "")
