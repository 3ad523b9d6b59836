"""Retarget the scene's hand-object motion onto another hand, as an action on its armature (Kinematic
Motion Retargeting, 2025), with the Retarget panel's settings (``scene.contact_edit_retarget``).

Interactively nothing makes Blender wait: the frames are read a few per timer tick (the scene steps
through them and comes back), then the contacts, the per-frame solves (in worker processes of its own),
the refinement and the spline run in a child process (:class:`solver.retarget.job.ChildRun`: a thread
of Blender's would hold its event loop back for half a second at a time), with the stage and the frames
done in the header and the progress indicator; the action is keyed when they are done, as one undo
step. Esc stops: frames solved so far are kept in the frames folder, so that Retarget again goes on from
them. Scripts and background mode run the same steps in turn, in Blender's process.

The annotation's operators are here too: *Propose* draws a starting annotation on a hand from its
armature (in a worker thread, :mod:`..operators.background`), *Export* writes a pair's as the
``annotation.json`` that ``contact-edit retarget --annotation`` reads.
"""

from __future__ import annotations

import time

import bpy
from bpy_extras.io_utils import ExportHelper

from solver.retarget import ChildRun, Stopped

from ..bridge import BridgeError
from ..operators.background import Background, Plan
from ..operators.common import USER_ERRORS, ExplainedPoll, guarded, mesh_object
from . import annotation
from . import scene as scene_retarget

#: Seconds of frame reading per timer tick, and between ticks.
READ_BUDGET = 0.04
TICK = 0.05
#: The stages in words, for the header.
STAGES = {
    "read": "reading frame",
    "contacts": "finding contacts",
    "transfer": "transferring contacts",
    "root": "solving roots, frame",
    "full": "solving poses, frame",
    "refine": "refining",
    "spline": "fitting splines",
    "metrics": "measuring",
}


def why_not_now(context) -> str | None:
    """One retarget at a time: a second would step the timeline while the first reads it, and compete with
    it for the cores."""
    running = (op for window in context.window_manager.windows for op in window.modal_operators)
    if any(op.bl_idname in ("contact_edit.retarget", "CONTACT_EDIT_OT_retarget") for op in running):
        return "A retarget is running: wait for it, or press Esc to stop it"
    return need_hands(context)


def need_hands(context) -> str | None:
    settings = context.scene.contact_edit_retarget
    chosen = (("source hand", settings.source), ("object", settings.held), ("target hand", settings.target))
    missing = [label for label, obj in chosen if obj is None]
    if missing:
        return f"Choose the {', the '.join(missing)} in the Retarget panel first"
    return None


def _inputs(context) -> dict:
    scene = context.scene
    s = scene.contact_edit_retarget
    start, end = (scene.frame_start, scene.frame_end) if s.use_scene_range else (s.frame_start, s.frame_end)
    return {
        "scene": scene,
        "source": s.source,
        "obj": s.held,
        "target": s.target,
        "frame_start": start,
        "frame_end": end,
        "annotation_path": s.annotation,
        "contacts": s.contacts,
        "folder": s.folder,
    }


class CONTACT_EDIT_OT_retarget(ExplainedPoll, bpy.types.Operator):
    """Retarget the source hand's motion with the object onto the target hand, keyed as a new action on its
    armature"""

    bl_idname = "contact_edit.retarget"
    bl_label = "Retarget"
    bl_options = {"REGISTER", "UNDO"}

    why_not = staticmethod(why_not_now)

    @guarded
    def execute(self, context):
        settings = context.scene.contact_edit_retarget
        outcome = scene_retarget.retarget_scene(
            **_inputs(context), workers=settings.workers or None, action_name=settings.action_name
        )
        return self._report(context, outcome)

    def _report(self, context, outcome) -> set:
        settings = context.scene.contact_edit_retarget
        settings.last = outcome.summary()
        self.report({"WARNING"} if outcome.result.warnings else {"INFO"}, settings.last)
        return {"FINISHED"}

    # ------------------------------------------------------------------ interactive

    @guarded
    def invoke(self, context, event):
        if context.area is None or context.window is None:
            return self.execute(context)
        self._reader, self._job, self._posed = scene_retarget.prepare(**_inputs(context))
        self._run = None
        self._stage = ("read", 0, self._reader.n_frames)
        self._began = time.monotonic()
        wm = context.window_manager
        self._timer = wm.event_timer_add(TICK, window=context.window)
        self._area = context.area
        wm.progress_begin(0, 1000)
        wm.modal_handler_add(self)
        self._show(context)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type == "ESC" and event.value == "PRESS":
            if self._run is None:  # still reading: nothing else started
                self._reader.restore()
                return self._end(context, {"CANCELLED"}, "Stopped reading the frames; nothing changed")
            self._run.stop()
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        try:
            if self._run is None:
                self._read(context)
            else:
                self._stage = self._run.poll()
                if self._run.done:
                    return self._finish(context)
        except USER_ERRORS as err:
            if self._run is None:
                self._reader.restore()
            return self._end(context, {"CANCELLED"}, str(err), error=True)
        self._show(context)
        return {"PASS_THROUGH"}

    def cancel(self, context):
        """Blender ends the operator (the window closes): the child stops, keeping its frames."""
        if self._run is not None:
            self._run.stop(wait=5.0)
        else:
            self._reader.restore()
        self._end(context, {"CANCELLED"})

    def _read(self, context) -> None:
        """Read frames for :data:`READ_BUDGET` seconds; when all are read, start the child process."""
        reader, until = self._reader, time.monotonic() + READ_BUDGET
        while time.monotonic() < until and reader.read_next():
            pass
        self._stage = ("read", reader.done, reader.n_frames)
        if reader.done == reader.n_frames:
            reader.restore()
            workers = context.scene.contact_edit_retarget.workers or None
            self._run = ChildRun(self._job, reader.motion(), workers)

    def _finish(self, context) -> set:
        try:
            outcome = self._run.outcome()
        except Stopped:
            return self._end(
                context,
                {"CANCELLED"},
                f"Stopped; nothing changed. The frames solved so far are kept in '{self._job.folder}': "
                "Retarget goes on from them",
            )
        except USER_ERRORS as err:
            return self._end(context, {"CANCELLED"}, f"The retarget failed: {err}", error=True)
        settings = context.scene.contact_edit_retarget
        try:
            scene_retarget.commit(self._job, self._posed, outcome, settings.action_name)
        except BridgeError as err:
            return self._end(context, {"CANCELLED"}, str(err), error=True)
        return self._end(context, self._report(context, outcome))

    def _show(self, context) -> None:
        stage, done, total = self._stage
        words = STAGES.get(stage, stage)
        count = f" {done} of {total}" if total > 1 else ""
        seconds = time.monotonic() - self._began
        stopping = self._run is not None and self._run.stopping
        stop = "stopping…" if stopping else "Esc: stop (solved frames are kept)"
        self._area.header_text_set(f"Retarget: {words}{count} · {seconds:.0f} s · {stop}")
        order = list(STAGES)
        share = (order.index(stage) + (done / total if total else 0.0)) / len(order) if stage in STAGES else 0
        context.window_manager.progress_update(int(1000 * share))

    def _end(self, context, status: set, message: str = "", error: bool = False) -> set:
        wm = context.window_manager
        wm.event_timer_remove(self._timer)
        wm.progress_end()
        self._area.header_text_set(None)
        if message:
            context.scene.contact_edit_retarget.last = message
            self.report({"ERROR"} if error else {"INFO"}, message)
        return status


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


classes = (
    CONTACT_EDIT_OT_retarget,
    CONTACT_EDIT_OT_annotation_propose,
    CONTACT_EDIT_OT_annotation_export,
)
