"""Work longer than a frame, off Blender's main thread, so that an operator never makes Blender wait: the
one way every long operator of the add-on runs (painting, axes, proposed annotations, the solve).

An operator splits what it does in two: ``work``, a function of plain data only (meshes, surface points,
patches, a contact IK problem — never Blender data, which is not thread-safe), and ``commit(context,
result)``, which stores the result in Blender data on the main thread. Started from the UI,
:meth:`Background.in_background` runs ``work`` in a worker thread and returns to Blender's event loop at
once: the viewport, the sidebar and navigation keep running, the header says what is being made and for
how long, Esc stops it (nothing changes; the thread's result is dropped when it ends), and the commit is
one undo step when the work is done. Scripts and ``blender --background`` call the operator's ``execute``,
which runs the same two functions one after the other: the same result, synchronously.

Work that reports as it goes and can stop early with what it has found so far (the solve, which finds
better and better poses) says so with a :class:`Live`: the worker reports through a :class:`Feed`, whose
stop flag it reads; the main thread shows each newer report as it arrives (the solve applies its best pose
so far) with Blender's progress indicator, Esc stops the work and commits what it found, and right-click
stops it and puts back what it started from.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from .. import store
from .common import guarded

#: Seconds between checks of the worker (and header updates) while it runs.
POLL_INTERVAL = 0.05
#: What the header says Esc does while a plan without a :class:`Live` runs.
ESC_DROPS = "Esc: stop (nothing changes)"


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

    def join(self) -> None:
        """Wait for the work to end (for work that has been asked to stop, see :class:`Feed`)."""
        self._thread.join()

    @property
    def error(self) -> BaseException | None:
        """What the work raised, if it did. Read once :attr:`done`."""
        return self._error

    def result(self) -> Any:
        """The work's return value; raises what the work raised. Call once :attr:`done`."""
        if self._error is not None:
            raise self._error
        return self._result


class Feed:
    """Between a worker and the main thread while live work runs: how many steps the work has taken, the
    latest step worth showing (the solve's best pose so far), and the main thread's request to stop,
    which the work reads each step."""

    def __init__(self):
        self._stop = threading.Event()
        self.count = 0
        self.latest: Any = None

    def report(self, count: int, latest: Any = None) -> bool:
        """From the worker: ``count`` steps taken, and ``latest`` (unless None) the step to show now.
        Returns whether the main thread asked the work to stop."""
        if latest is not None:
            self.latest = latest
        self.count = count
        return self._stop.is_set()

    def stop(self) -> None:
        """From the main thread: ask the work to stop at its next step."""
        self._stop.set()

    @property
    def stopped(self) -> bool:
        """Whether the work was asked to stop."""
        return self._stop.is_set()


@dataclass(frozen=True)
class Live:
    """What a :class:`Plan` adds when its work reports as it goes through ``feed`` and stops when asked
    (the solve). On the main thread, while the work runs, each timer tick (every ``interval`` seconds)
    that finds a newer report calls ``show(context, latest, count)``, which shows it (the solve applies
    the pose) and returns the header's text; Blender's progress indicator counts the steps up to
    ``total``, and the header ends with ``keys`` (what Esc and right-click do). Esc asks the work to stop,
    waits for it and commits what it returns; right-click asks it to stop, waits for it and calls
    ``restore(context)``, which puts back what the work started from and returns the operator's status.
    If the work raises, ``failed(context, error)`` reports it and returns the status."""

    feed: Feed
    show: Callable[[Any, Any, int], str]
    restore: Callable[[Any], set]
    failed: Callable[[Any, BaseException], set]
    total: int
    keys: str
    interval: float = POLL_INTERVAL


@dataclass(frozen=True)
class Plan:
    """What an operator does when it is slow: ``work()`` on plain data, any thread; ``commit(context,
    result)`` stores the result on the main thread and returns the operator's status; ``label`` says
    what is being made ("Making a patch of 240 points on 'Hand'"). ``watched``: objects whose contacts
    the work started from; if any of them changes meanwhile (the user keeps working), the result is
    stale and is not stored. ``live``: for work that reports as it goes (see :class:`Live`). ``thread``
    names the worker thread (default: from the label)."""

    label: str
    work: Callable[[], Any]
    commit: Callable[[Any, Any], set]
    watched: tuple = ()
    live: Live | None = None
    thread: str = ""


class Background:
    """Mixin for an operator whose slow part runs in a worker thread (see the module docstring).

    Its planning step returns a :class:`Plan`, or the operator's status when nothing is left to do (an
    error reported, a quick change made). ``execute`` hands it to :meth:`now`, ``invoke`` (or the
    ``modal`` that ends a stroke) to :meth:`in_background`. While :meth:`waiting`, events go to
    :meth:`modal_background`: this mixin's ``modal`` does just that, and an operator with a modal of its
    own (a brush stroke) hands them on itself. The mixin's own state and helpers are named
    ``_job…`` (and ``_show_wait``, ``_end_wait``), so that they never meet an operator's.
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
        self._job = Job(plan.work, plan.thread or f"contact-edit: {plan.label}")
        self._job_plan, self._job_began, self._job_shown = plan, time.monotonic(), 0
        self._job_started_from = [(obj, obj.contact_edit.layer, store.text(obj)) for obj in plan.watched]
        wm, live = context.window_manager, plan.live
        self._job_timer = wm.event_timer_add(
            POLL_INTERVAL if live is None else live.interval, window=context.window
        )
        self._job_area = context.area
        if live is None:
            self._show_wait(context)
        else:
            wm.progress_begin(0, live.total)
            self._job_area.header_text_set(f"{plan.label}… · {live.keys}")
        if add_handler:
            wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def waiting(self) -> bool:
        return getattr(self, "_job", None) is not None

    @guarded
    def modal(self, context, event) -> set:
        return self.modal_background(context, event)

    def modal_background(self, context, event) -> set:
        """Esc stops (live work with what it found, other work with nothing changed); right-click stops
        live work and puts back what it started from; when the worker is done, its result is committed;
        every other event goes on to Blender (the user keeps working)."""
        live, pressed = self._job_plan.live, event.value == "PRESS"
        if event.type == "ESC" and pressed:
            if live is None:
                self._end_wait(context)
                self.report({"INFO"}, f"Stopped {self._job_doing()}; nothing changed")
                return {"CANCELLED"}
            live.feed.stop()
            self._job.join()
            return self._job_finish(context)
        if event.type == "RIGHTMOUSE" and pressed and live is not None:
            live.feed.stop()
            self._job.join()
            self._end_wait(context)
            return live.restore(context)
        if event.type == "TIMER":
            if self._job.done:
                return self._job_finish(context)
            self._show_wait(context)
        return {"PASS_THROUGH"}

    def _job_finish(self, context) -> set:
        """The work has ended: its result committed, unless the contacts it started from changed."""
        job, live = self._end_wait(context), self._job_plan.live
        if live is not None and job.error is not None:
            return live.failed(context, job.error)
        changed = self._job_changed()
        if changed:  # a warning: an error's popup would land wherever the user is working now
            self.report(
                {"WARNING"},
                f"The contacts of {changed} changed while {self._job_doing()}; nothing was stored: do it "
                "again",
            )
            return {"CANCELLED"}
        return self._job_plan.commit(context, job.result())

    def _job_doing(self) -> str:
        label = self._job_plan.label
        return label[:1].lower() + label[1:]

    def _job_changed(self) -> str:
        """The watched objects whose contacts are not what the work started from (or that are gone)."""
        names = []
        for obj, layer, data in self._job_started_from:
            try:
                if store.text(obj, layer) != data:
                    names.append(f"'{obj.name}'")
            except ReferenceError:  # deleted meanwhile
                names.append("a deleted object")
        return " and ".join(names)

    def _show_wait(self, context) -> None:
        """The header while the work runs: for how long so far, or, for live work, its newest report
        (shown by :attr:`Live.show`) and the steps in Blender's progress indicator."""
        live = self._job_plan.live
        if live is None:
            seconds = time.monotonic() - self._job_began
            self._job_area.header_text_set(f"{self._job_plan.label}… {seconds:.1f} s · {ESC_DROPS}")
            return
        latest, count = live.feed.latest, live.feed.count
        if latest is None or count == self._job_shown:
            return
        self._job_shown = count
        text = live.show(context, latest, count)
        context.window_manager.progress_update(count)
        self._job_area.header_text_set(f"{text} · {live.keys}")

    def _end_wait(self, context) -> Job:
        job, self._job = self._job, None
        wm = context.window_manager
        wm.event_timer_remove(self._job_timer)
        if self._job_plan.live is not None:
            wm.progress_end()
        self._job_area.header_text_set(None)
        store.redraw()  # every editor: live work may have changed what all of them show (a pose)
        return job
