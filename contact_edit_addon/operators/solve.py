"""Pose the hand's armature from the contacts: contact IK (§4.4) and flex-to-contact (1988).

Interactively, the solve runs in a worker thread (it is pure numpy; Blender data is only touched here,
on the main thread) and the viewport shows each better pose as it is found, as the user study asked.
Esc stops and keeps the best pose so far; right-click cancels and puts back the pose it started from.
Either way the header, the status bar and the panel say which happened.
"""

from __future__ import annotations

import threading

import bpy

from .. import bridge, posing, preferences, store
from .common import HotkeyTool, guarded, need_hand_and_object

#: Viewport refreshes per second while solving.
REDRAW_RATE = 30.0


def need_pairs(context) -> str | None:
    hand, reason = context.scene.contact_edit.hand, need_hand_and_object(context)
    if reason is None and not any(e.pair for e in hand.contact_edit.patches):
        reason = f"No patch of '{hand.name}' is paired yet: transfer one onto the object"
    return reason


class CONTACT_EDIT_OT_solve(HotkeyTool, bpy.types.Operator):
    """Pose the hand's armature so that its contact patches meet their pairs on the object"""

    bl_idname = "contact_edit.solve"
    bl_label = "Solve Pose"
    bl_options = {"REGISTER", "UNDO"}

    stage: bpy.props.EnumProperty(name="Solve", items=posing.STAGES, default="ALL")
    keyframe: bpy.props.BoolProperty(name="Keyframe", description="Key the solved pose on the current frame")
    max_evaluations: bpy.props.IntProperty(
        name="Evaluations", default=2000, min=1, description="Stop after this many energy evaluations"
    )

    why_not = staticmethod(need_pairs)

    @guarded
    def execute(self, context):
        problem = posing.problem(context.scene, self.stage)
        result = problem.ik.solve(problem.theta0, problem.free, max_evaluations=self.max_evaluations)
        self._finish(context, problem, result)
        return {"FINISHED"}

    def _finish(self, context, problem, result, outcome: str | None = None) -> None:
        problem.apply(result.theta, context.scene.frame_current if self.keyframe else None)
        message = posing.summary(context.scene, problem, result, outcome)
        off = posing.rig_mismatch(context.scene, problem, result.theta)
        if off:
            message += f"; {off}"
        context.scene.contact_edit.last_solve = message
        warn = off or (outcome or result.status) in posing.WARNINGS
        self.report({"WARNING"} if warn else {"INFO"}, message)

    # ------------------------------------------------------------------ interactive

    @guarded
    def invoke(self, context, event):
        if context.area is None or context.window is None:
            return self.execute(context)
        self._problem = posing.problem(context.scene, self.stage)
        self._latest = self._result = self._error = None
        self._shown = self._evaluations = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._work, name="contact-edit solve", daemon=True)
        self._thread.start()
        self._timer = context.window_manager.event_timer_add(1.0 / REDRAW_RATE, window=context.window)
        context.window_manager.progress_begin(0, self.max_evaluations)
        context.window_manager.modal_handler_add(self)
        context.area.header_text_set("Solving… · Esc: stop and keep the best pose · Right-click: cancel")
        return {"RUNNING_MODAL"}

    def _work(self) -> None:
        """The solve, off the main thread; it only records progress and the result."""
        problem = self._problem

        def progress(step):
            if self._latest is None or step.energy < self._latest.energy:
                self._latest = step  # the viewport shows the best pose so far, not every trial
            self._evaluations = step.iteration
            return self._stop.is_set()

        try:
            self._result = problem.ik.solve(problem.theta0, problem.free, progress, self.max_evaluations)
        except Exception as err:  # reported on the main thread
            self._error = err

    def modal(self, context, event):
        if event.type in {"ESC", "RIGHTMOUSE"} and event.value == "PRESS":
            self._stop.set()
            self._thread.join()
            if event.type == "RIGHTMOUSE":
                self._problem.apply(self._problem.theta0)
                context.scene.contact_edit.last_solve = "Cancelled; the pose is as it was before the solve"
                self.report({"INFO"}, context.scene.contact_edit.last_solve)
                return self._end(context, {"CANCELLED"})
            stopped = self._result is not None and self._result.status == "cancelled"
            return self._done(context, "kept" if stopped else None)
        if self._thread.is_alive():
            if event.type == "TIMER":
                self._show_progress(context)
            return {"PASS_THROUGH"}
        return self._done(context)

    def _show_progress(self, context) -> None:
        step = self._latest
        if step is None or self._evaluations == self._shown:
            return
        self._shown = self._evaluations
        self._problem.apply(step.theta)
        context.window_manager.progress_update(self._evaluations)
        terms = ", ".join(f"{k} {v:.3g}" for k, v in step.terms.items() if v)
        context.area.header_text_set(
            f"Solving: {self._evaluations} of at most {self.max_evaluations} evaluations, best energy "
            f"{step.energy:.4g} ({terms}) · Esc: stop and keep the best pose · Right-click: cancel"
        )

    def _done(self, context, outcome: str | None = None) -> set:
        if self._error is not None:
            self._problem.apply(self._problem.theta0)
            context.scene.contact_edit.last_solve = f"The solve failed; the pose is as it was: {self._error}"
            self.report({"ERROR"}, context.scene.contact_edit.last_solve)
            return self._end(context, {"CANCELLED"})
        self._finish(context, self._problem, self._result, outcome)
        return self._end(context, {"FINISHED"})

    def _end(self, context, status: set) -> set:
        context.window_manager.event_timer_remove(self._timer)
        context.window_manager.progress_end()
        context.area.header_text_set(None)
        store.redraw()
        return status


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
    joints: bpy.props.EnumProperty(
        name="Joints",
        items=[
            ("TOGETHER", "Together", "Curl a chain's joints together: the fingertips close first"),
            ("IN_TURN", "In turn", "Curl one joint at a time from the first: the fingers wrap the object"),
        ],
        default="TOGETHER",
    )
    keyframe: bpy.props.BoolProperty(name="Keyframe", description="Key the pose on the current frame")

    why_not = staticmethod(need_hand_and_object)

    @guarded
    def execute(self, context):
        sign = 1 if self.direction == "POSITIVE" else -1
        curl = "in turn" if self.joints == "IN_TURN" else "together"
        posed, result = posing.flex(context.scene, sign, curl)
        bridge.apply_pose(posed, result.theta, context.scene.frame_current if self.keyframe else None)
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
        self.report({"INFO"} if reached and not inside else {"WARNING"}, message)
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
