"""Work longer than a frame, off Blender's main thread, so that an operator never makes Blender wait.

An operator splits what it does in two: ``work``, a function of plain data only (meshes, surface points,
patches — never Blender data, which is not thread-safe), and ``commit(context, result)``, which stores
the result in Blender data on the main thread. Started from the UI, :meth:`Background.in_background`
runs ``work`` in a worker thread and returns to Blender's event loop at once: the viewport, the sidebar
and navigation keep running, the header says what is being made and for how long, Esc stops it
(nothing changes; the thread's result is dropped when it ends), and the commit is one undo step when
the work is done. Scripts and ``blender --background`` call the operator's ``execute``, which runs the
same two functions one after the other: the same result, synchronously.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from .. import store

#: Seconds between checks of the worker (and header updates) while it runs.
POLL_INTERVAL = 0.05


class Job:
    """``work()`` running in a daemon thread; its result or exception once :attr:`done`."""

    def __init__(self, work: Callable[[], Any], name: str):
        self._result: Any = None
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, args=(work,), name=name, daemon=True)
        self._thread.start()

    def _run(self, work) -> None:
        try:
            self._result = work()
        except BaseException as err:  # handed to the main thread by result()
            self._error = err

    @property
    def done(self) -> bool:
        return not self._thread.is_alive()

    def result(self) -> Any:
        """The work's return value; raises what the work raised. Call once :attr:`done`."""
        if self._error is not None:
            raise self._error
        return self._result


@dataclass(frozen=True)
class Plan:
    """What an operator does when it is slow: ``work()`` on plain data, any thread; ``commit(context,
    result)`` stores the result on the main thread and returns the operator's status; ``label`` says
    what is being made ("Making a patch of 240 points on 'Hand'"). ``watched``: objects whose contacts
    the work started from; if any of them changes meanwhile (the user keeps working), the result is
    stale and is not stored."""

    label: str
    work: Callable[[], Any]
    commit: Callable[[Any, Any], set]
    watched: tuple = ()


class Background:
    """Mixin for an operator whose slow part runs in a worker thread (see the module docstring).

    Its planning step returns a :class:`Plan`, or the operator's status when nothing is left to do (an
    error reported, a quick change made). ``execute`` hands it to :meth:`now`, ``invoke`` (or the
    ``modal`` that ends a stroke) to :meth:`in_background`; ``modal`` hands its events to
    :meth:`modal_background` while :meth:`waiting`.
    """

    def now(self, context, plan: Plan | set) -> set:
        """The plan's work and commit, one after the other (scripts, background mode)."""
        if isinstance(plan, set):
            return plan
        return plan.commit(context, plan.work())

    def in_background(self, context, plan: Plan | set, add_handler: bool = True) -> set:
        """Run the plan's work off the main thread and its commit on it when done; without a window
        (background mode), :meth:`now`. ``add_handler`` is False for an operator that is running modal
        already."""
        if isinstance(plan, set) or context.window is None or context.area is None:
            return self.now(context, plan)
        self._job = Job(plan.work, f"contact-edit: {plan.label}")
        self._plan, self._began = plan, time.monotonic()
        self._started_from = [(obj, obj.contact_edit.layer, store.text(obj)) for obj in plan.watched]
        wm = context.window_manager
        self._job_timer = wm.event_timer_add(POLL_INTERVAL, window=context.window)
        self._job_area = context.area
        self._show_wait(0.0)
        if add_handler:
            wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def waiting(self) -> bool:
        return getattr(self, "_job", None) is not None

    def modal_background(self, context, event) -> set:
        """Esc stops; when the worker is done, its result is committed; every other event goes on to
        Blender (the user keeps working)."""
        if event.type == "ESC" and event.value == "PRESS":
            self._end_wait(context)
            self.report({"INFO"}, f"Stopped {self._doing()}; nothing changed")
            return {"CANCELLED"}
        if event.type == "TIMER":
            if self._job.done:
                job = self._end_wait(context)
                changed = self._changed()
                if changed:  # a warning: an error's popup would land wherever the user is working now
                    self.report(
                        {"WARNING"},
                        f"The contacts of {changed} changed while {self._doing()}; nothing was stored: do it "
                        "again",
                    )
                    return {"CANCELLED"}
                return self._plan.commit(context, job.result())
            self._show_wait(time.monotonic() - self._began)
        return {"PASS_THROUGH"}

    def _doing(self) -> str:
        label = self._plan.label
        return label[:1].lower() + label[1:]

    def _changed(self) -> str:
        """The watched objects whose contacts are not what the work started from (or that are gone)."""
        names = []
        for obj, layer, data in self._started_from:
            try:
                if store.text(obj, layer) != data:
                    names.append(f"'{obj.name}'")
            except ReferenceError:  # deleted meanwhile
                names.append("a deleted object")
        return " and ".join(names)

    def _show_wait(self, seconds: float) -> None:
        self._job_area.header_text_set(f"{self._plan.label}… {seconds:.1f} s · Esc: stop (nothing changes)")

    def _end_wait(self, context) -> Job:
        job, self._job = self._job, None
        context.window_manager.event_timer_remove(self._job_timer)
        self._job_area.header_text_set(None)
        self._job_area.tag_redraw()
        return job
