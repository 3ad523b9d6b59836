"""Bulk contact transfer through a hand-pair annotation (Kinematic Motion Retargeting §3.3.2).

:class:`ContactTransfer` moves contacts through :class:`geodesics.ContactAtlas`: all frames' contacts in
one parameterize-and-trace call (duplicates across frames are traced once), then split back into frames
with a kept mask, so the object's contacts stay paired with the hand's row for row.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from geodesics import Axis, ContactAtlas, SurfacePoints, TriMesh

from .annotations import AnnotationError, HandPairAnnotation

if TYPE_CHECKING:  # pragma: no cover
    from .motion import Contacts, Motion


class ContactTransfer:
    """The contact atlas of an annotated hand pair, laid out once, moving contacts in bulk.

    Parameters
    ----------
    annotation : HandPairAnnotation
    source_mesh, target_mesh : TriMesh
        The annotated hands' rest meshes (checked against the annotation).

    Raises
    ------
    AnnotationError
        If the meshes are not the annotated ones, or a curve cannot be laid out on the target.
    """

    def __init__(self, annotation: HandPairAnnotation, source_mesh: TriMesh, target_mesh: TriMesh):
        from geodesics import ContactError

        annotation.check(source_mesh, target_mesh)
        self.annotation = annotation
        self.source_mesh, self.target_mesh = source_mesh, target_mesh
        try:
            curves = {c.name: Axis(source_mesh, c.source) for c in annotation.curves}
            self.atlas = ContactAtlas(source_mesh, curves)
            kept = [c for c in annotation.curves if not c.dropped]
            self.target_curves = self.atlas.lay_out(
                target_mesh,
                {c.name: (c.target_start, c.target_direction) for c in kept},
                {c.name: c.axis_scale for c in kept},
            )
        except ContactError as e:
            raise AnnotationError(f"the annotation's curves cannot be laid out: {e}") from None
        self.radial_scale = {c.name: c.radial_scale for c in kept}

    def points(self, contacts: SurfacePoints) -> tuple[SurfacePoints, np.ndarray]:
        """Transfer surface points of the source hand.

        Returns the kept points on the target (in order) and the (k,) kept mask. Repeated points (the
        same face and barycentric coordinates, as across frames of a motion) are traced once.
        """
        contacts.validate(self.source_mesh)
        k = len(contacts)
        if k == 0:
            return SurfacePoints(np.empty(0, np.int64), np.empty((0, 3))), np.zeros(0, bool)
        key = np.column_stack([contacts.faces.astype(np.float64), contacts.bary])
        unique, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
        inverse = inverse.reshape(-1)
        moved, kept_unique = self.atlas.transfer(
            contacts[first], self.target_curves, self.radial_scale, self.annotation.threshold
        )
        slot = np.full(len(unique), -1, np.int64)
        slot[kept_unique] = np.arange(int(kept_unique.sum()))
        kept = kept_unique[inverse]
        rows = slot[inverse[kept]]
        return SurfacePoints(moved.faces[rows], moved.bary[rows]), kept

    def contacts(self, contacts: Contacts, progress: Callable[[int, int], None] | None = None):
        """Transfer every frame's hand contacts in one call.

        Returns
        -------
        moved : Contacts
            The kept contacts on the target hand, frame by frame.
        kept : (K,) bool
            Which of the input rows were kept; apply it to the paired object contacts with
            :func:`keep_rows` so they stay paired row for row.
        """
        from .motion import Contacts as _Contacts

        points = SurfacePoints(contacts.faces, contacts.bary)
        if progress is not None:
            progress(0, 1)
        moved, kept = self.points(points)
        if progress is not None:
            progress(1, 1)
        offsets = _kept_offsets(np.asarray(contacts.offsets), kept)
        return _Contacts(offsets, moved.faces, moved.bary), kept


def _kept_offsets(offsets: np.ndarray, kept: np.ndarray) -> np.ndarray:
    counts = np.diff(offsets)
    frame = np.repeat(np.arange(counts.size), counts)
    kept_counts = np.bincount(frame[kept], minlength=counts.size)
    return np.concatenate([[0], np.cumsum(kept_counts)]).astype(np.int64)


def keep_rows(contacts: Contacts, kept) -> Contacts:
    """The rows of ``contacts`` where ``kept`` (K,) is True, frames preserved."""
    from .motion import Contacts as _Contacts

    kept = np.asarray(kept, dtype=bool)
    if kept.shape != (len(contacts.faces),):
        raise AnnotationError(
            f"kept must have one flag per contact ({len(contacts.faces)}), got {kept.shape}"
        )
    return _Contacts(
        _kept_offsets(np.asarray(contacts.offsets), kept), contacts.faces[kept], contacts.bary[kept]
    )


@dataclass(frozen=True, eq=False)
class TransferredContacts:
    """A motion's contacts moved to the target hand.

    Attributes
    ----------
    hand_contacts : Contacts
        On the target hand's mesh.
    object_contacts : Contacts or None
        The motion's object contacts that stay paired with them, row for row.
    kept : (K,) bool
        Which of the motion's hand contacts were kept.
    """

    hand_contacts: Contacts
    object_contacts: Contacts | None
    kept: np.ndarray


def transfer_motion(
    motion: Motion,
    annotation: HandPairAnnotation,
    target_mesh: TriMesh,
    progress: Callable[[int, int], None] | None = None,
) -> TransferredContacts:
    """Transfer a motion's hand contacts (all frames at once) onto the target hand (§3.3.2)."""
    if motion.hand_contacts is None:
        raise AnnotationError("the motion has no hand contacts; pair them first (pairing.pair_motion)")
    transfer = ContactTransfer(annotation, motion.hand_mesh, target_mesh)
    moved, kept = transfer.contacts(motion.hand_contacts, progress)
    obj = None if motion.object_contacts is None else keep_rows(motion.object_contacts, kept)
    return TransferredContacts(moved, obj, kept)
