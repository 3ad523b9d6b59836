"""Pose the hand's armature from the contacts: contact IK (§4.4) and flex-to-contact (1988).

Interactively, the solve runs in a worker thread (it is pure numpy; Blender data is only touched on the
main thread), as every long operator's work does (:mod:`.background`), and the viewport shows each better
pose as it is found, as the user study asked. Esc stops and keeps the best pose so far; right-click
cancels and puts back the pose it started from. Either way the header, the status bar and the panel say
which happened.
"""

from __future__ import annotations

import bpy
import numpy as np

from .. import bridge, posing, preferences, store
from .background import Background, Feed, Live, Plan
from .common import KEYFRAME, HotkeyTool, guarded, key_frame, keyed, need_hand_and_object

#: Viewport refreshes per second while solving.
REDRAW_RATE = 30.0
#: What the header says the keys do while solving.
KEYS = "Esc: stop and keep the best pose · Right-click: cancel"


def need_pairs(context) -> str | None:
    hand, reason = context.scene.contact_edit.hand, need_hand_and_object(context)
    if reason is None and not any(e.pair for e in hand.contact_edit.patches):
        reason = f"No patch of '{hand.name}' is paired yet: transfer one onto the object"
    return reason


class CONTACT_EDIT_OT_solve(Background, HotkeyTool, bpy.types.Operator):
    """Pose the hand's armature so that its contact patches meet their pairs on the object"""

    bl_idname = "contact_edit.solve"
    bl_label = "Solve Pose"
    bl_options = {"REGISTER", "UNDO"}

    stage: bpy.props.EnumProperty(name="Solve", items=posing.STAGES, default="ALL")
    start: bpy.props.EnumProperty(name="Start", items=posing.STARTS, default="AUTO")
    keyframe: bpy.props.BoolProperty(**KEYFRAME)
    max_evaluations: bpy.props.IntProperty(
        name="Evaluations", default=2000, min=1, description="Stop after this many energy evaluations"
    )

    why_not = staticmethod(need_pairs)

    @classmethod
    def description(cls, context, properties) -> str:
        """Each stage's button says what it frees (the panel's Root, Fingers, All and Selected)."""
        stage = next(text for key, _, text in posing.STAGES if key == properties.stage)
        return f"{cls.__doc__}. {stage}"

    @guarded
    def execute(self, context):
        return self.now(context, self._plan(context))

    @guarded
    def invoke(self, context, event):
        return self.in_background(context, self._plan(context))

    def _plan(self, context) -> Plan:
        """The solve as background work: set up on the main thread (:func:`posing.problem`), solved off it
        with each better pose shown as it is found (the viewport shows the best so far, not every
        trial), then written back and said how it went."""
        problem, limit, feed = posing.problem(context.scene, self.stage), self.max_evaluations, Feed()

        def progress(step) -> bool:
            better = feed.latest is None or not np.array_equal(step.theta, feed.latest.theta)
            return feed.report(step.iteration, step if better else None)

        start = posing.START_MODES[self.start]

        def work():
            return problem.ik.solve(problem.theta0, problem.free, progress, limit, start=start)

        def commit(context, result) -> set:
            kept = feed.stopped and result.status == "cancelled"  # Esc: the best pose so far
            self._finish(context, problem, result, "kept" if kept else None)
            return {"FINISHED"}

        def show(context, step, evaluations: int) -> str:
            problem.apply(step.theta)
            terms = ", ".join(f"{k} {v:.3g}" for k, v in step.terms.items() if v)
            return (
                f"Solving: {evaluations} of at most {limit} evaluations, best energy {step.energy:.4g} "
                f"({terms})"
            )

        before = context.scene.contact_edit.last_solve  # what the panel says of the pose a cancel puts back

        def restore(context) -> set:
            message = "Cancelled; the pose is as it was before the solve"
            return self._put_back(context, problem, {"INFO"}, message, panel=before)

        def failed(context, error) -> set:
            return self._put_back(
                context, problem, {"ERROR"}, f"The solve failed; the pose is as it was: {error}"
            )

        live = Live(feed, show, restore, failed, total=limit, keys=KEYS, interval=1.0 / REDRAW_RATE)
        return Plan("Solving", work, commit, live=live, thread="contact-edit solve")

    def _finish(self, context, problem, result, outcome: str | None = None) -> None:
        frame = key_frame(self, context)
        problem, result = posing.settle(context.scene, problem, result, self.stage, frame)
        message = posing.summary(context.scene, problem, result, outcome) + keyed(frame)
        off = posing.rig_mismatch(context.scene, problem, result.theta)
        if off:
            message += f"; {off}"
        context.scene.contact_edit.last_solve = message
        warn = off or (outcome or result.status) in posing.WARNINGS
        self.report({"WARNING"} if warn else {"INFO"}, message)

    def _put_back(self, context, problem, level: set, message: str, panel: str | None = None) -> set:
        """The pose the solve started from, and ``message`` in a report and on the panel (or ``panel``
        there: after a cancel, what it said of the pose put back)."""
        problem.apply(problem.theta0)
        context.scene.contact_edit.last_solve = message if panel is None else panel
        self.report(level, message)
        return {"CANCELLED"}


#: How Flex to Contact curls a chain's joints: the panel's Flex and Wrap.
CURLS = (
    ("TOGETHER", "Together", "Curl a chain's joints together: the fingertips close first"),
    ("IN_TURN", "In turn", "Curl one joint at a time from the first: the fingers wrap the object"),
)


class CONTACT_EDIT_OT_flex_to_contact(HotkeyTool, bpy.types.Operator):
    """Curl the selected finger bones until they touch the object (a quick first grip)"""

    bl_idname = "contact_edit.flex_to_contact"
    bl_label = "Flex to Contact"
    bl_options = {"REGISTER", "UNDO"}

    direction: bpy.props.EnumProperty(
        name="Curl",
        items=[
            ("POSITIVE", "Positive X", "Curl by increasing each bone's X rotation"),
            ("NEGATIVE", "Negative X", "Curl by decreasing each bone's X rotation"),
        ],
        default="POSITIVE",
    )
    joints: bpy.props.EnumProperty(name="Joints", items=CURLS, default="TOGETHER")
    keyframe: bpy.props.BoolProperty(**KEYFRAME)

    why_not = staticmethod(need_hand_and_object)

    @classmethod
    def description(cls, context, properties) -> str:
        """Flex and Wrap say how each curls."""
        joints = next(text for key, _, text in CURLS if key == properties.joints)
        return f"{cls.__doc__}. {joints}"

    @guarded
    def execute(self, context):
        sign = 1 if self.direction == "POSITIVE" else -1
        curl = "in turn" if self.joints == "IN_TURN" else "together"
        posed, result = posing.flex(context.scene, sign, curl)
        frame = key_frame(self, context)
        bridge.apply_pose(posed, result.theta, frame)
        scene, target = context.scene, context.scene.contact_edit.target.name
        scale = bridge.uniform_scale(posed.armature_object())
        reached = [name for name, hit in result.touching.items() if hit]
        inside = {name: d for name, d in result.distance.items() if d < 0}
        missed = [name for name in result.touching if name not in reached and name not in inside]
        message = f"{len(reached)} of {len(result.touching)} chains touch '{target}'"
        if inside:
            depths = ", ".join(
                f"{name} ({posing.length_text(scene, -d * scale)} deep)" for name, d in inside.items()
            )
            message += f"; inside it already before curling: {depths}"
        if missed:
            message += f"; curled fully without touching: {', '.join(missed)}"
        self.report({"INFO"} if reached and not inside else {"WARNING"}, message + keyed(frame))
        return {"FINISHED"}


class CONTACT_EDIT_OT_check_rig(bpy.types.Operator):
    """Read the hand's rig again and say whether contact IK can pose it (after changing the rig)"""

    bl_idname = "contact_edit.check_rig"
    bl_label = "Check Rig"

    def execute(self, context):
        report = posing.check_rig(context.scene)
        self.report({"INFO"} if report.ok else {"WARNING"}, "; ".join(report.lines))
        store.redraw()
        return {"FINISHED"}


class CONTACT_EDIT_OT_reset_weights(bpy.types.Operator):
    """Set the scene's solver weights to the defaults in the add-on's preferences"""

    bl_idname = "contact_edit.reset_weights"
    bl_label = "Reset Weights"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        for name, value in preferences.solver_weights(context).items():
            setattr(context.scene.contact_edit, name, value)
        return {"FINISHED"}


classes = (
    CONTACT_EDIT_OT_solve,
    CONTACT_EDIT_OT_flex_to_contact,
    CONTACT_EDIT_OT_check_rig,
    CONTACT_EDIT_OT_reset_weights,
)
