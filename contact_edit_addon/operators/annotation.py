"""A hand's retargeting annotation: propose one from its armature, and export a pair's as annotation.json."""

from __future__ import annotations

import bpy
from bpy_extras.io_utils import ExportHelper

from .. import annotation
from .background import Background, Plan
from .common import ExplainedPoll, guarded, mesh_object


class CONTACT_EDIT_OT_annotation_propose(Background, ExplainedPoll, bpy.types.Operator):
    """Draw a starting retargeting annotation on the hand from its armature: a curve along each finger's
    palmar side and two across the palm, markers on the joints, tips, knuckles and wrist (replaces the
    hand's annotation)"""

    bl_idname = "contact_edit.annotation_propose"
    bl_label = "Propose Annotation"
    bl_options = {"REGISTER", "UNDO"}

    object_name: bpy.props.StringProperty(
        name="Hand", description="The hand mesh (default: the active object)"
    )
    wrist: bpy.props.StringProperty(
        name="Wrist bone",
        description="The bone the fingers hang from (empty: found; name it when the armature has two hands)",
    )
    palmar: bpy.props.EnumProperty(
        name="Palm side",
        items=[
            ("AUTO", "Found", "The side the fingers curl to at rest"),
            ("+Z", "+Z", "The finger bones' local +Z axis"),
            ("-Z", "-Z", "The finger bones' local -Z axis"),
            ("+X", "+X", "The finger bones' local +X axis"),
            ("-X", "-X", "The finger bones' local -X axis"),
        ],
        default="AUTO",
        description="Which side of the finger bones is the palm's",
    )

    @guarded
    def invoke(self, context, event):
        return self.in_background(context, self._plan(context))

    @guarded
    def modal(self, context, event):
        return self.modal_background(context, event)

    @guarded
    def execute(self, context):
        return self.now(context, self._plan(context))

    def _plan(self, context) -> Plan:
        hand = mesh_object(context, self.object_name or None)
        palmar = None if self.palmar == "AUTO" else self.palmar
        work = annotation.proposal_work(hand, self.wrist, palmar)
        where = hand.name

        def commit(context, proposal):
            hand = mesh_object(context, where)
            annotation.keep(hand, proposal)
            self.report(
                {"INFO"},
                f"Proposed on '{hand.name}' from '{proposal.wrist}': {', '.join(proposal.chains)}; "
                f"{len(proposal.markers)} markers; palm side {proposal.palmar} of the finger bones",
            )
            return {"FINISHED"}

        return Plan(f"Proposing an annotation for '{hand.name}'", work, commit, (hand,))


def _need_pair(context) -> str | None:
    settings = context.scene.contact_edit_retarget
    for role, obj in (("source", settings.source), ("target", settings.target)):
        if obj is None:
            return f"Choose the {role} hand in Retarget first"
        if not annotation.has_annotation(obj):
            return f"The {role} hand '{obj.name}' has no annotation yet: propose or draw one"
    return None


class CONTACT_EDIT_OT_annotation_export(ExplainedPoll, bpy.types.Operator, ExportHelper):
    """Write the source and target hands' annotations as the annotation.json that contact-edit retarget
    reads (--annotation)"""

    bl_idname = "contact_edit.annotation_export"
    bl_label = "Export Annotation"
    filename_ext = ".json"
    filter_glob: bpy.props.StringProperty(default="*.json", options={"HIDDEN"})

    why_not = staticmethod(_need_pair)

    @guarded
    def execute(self, context):
        settings = context.scene.contact_edit_retarget
        pair = annotation.hand_pair(settings.source, settings.target)
        pair.save(self.filepath)  # written atomically: never half a file
        self.report({"INFO"}, f"Wrote {self.filepath}: {annotation.summary(pair)}")
        return {"FINISHED"}


classes = (CONTACT_EDIT_OT_annotation_propose, CONTACT_EDIT_OT_annotation_export)
