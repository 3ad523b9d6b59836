"""Inside a real Blender window: runs one scripted session and records what it saw.

The harness (:mod:`tests.window.harness`) starts Blender with ``--python-expr`` that calls
:func:`start` with a session module's name. The module defines ``steps(s)``, a generator that receives
a :class:`Session` and yields how many seconds to wait before it goes on; Blender's event loop runs
(draws, handles input) while it waits, so real input events sent with ``xdotool`` arrive the way a
user's do. Input helpers that need the event loop between events (``move``, ``drag``, ``key``) are
generators themselves: ``yield from s.drag(...)``.

When the generator ends (or raises), the session writes ``results.json`` (what it recorded, and the
traceback if any) into its folder and quits Blender. This file runs inside Blender only; it imports
nothing from the project.
"""

from __future__ import annotations

import importlib
import json
import os
import subprocess
import sys
import time
import traceback
from dataclasses import dataclass

import bpy
import numpy as np
from bpy_extras import view3d_utils

#: The folder the harness gave this session (results, screenshots).
FOLDER = os.environ.get("CONTACT_EDIT_SESSION", "/tmp")


@dataclass
class View:
    """The largest 3D viewport: its window, area, main region and view."""

    window: bpy.types.Window
    area: bpy.types.Area
    region: bpy.types.Region
    rv3d: bpy.types.RegionView3D

    def override(self):
        """A context for operators and UI calls in this viewport."""
        return bpy.context.temp_override(
            window=self.window, screen=self.window.screen, area=self.area, region=self.region
        )

    def project(self, world) -> np.ndarray:
        """(k, 2) screen pixels (x right, y down, as xdotool and screenshots count them) of world points;
        NaN where a point is behind the view."""
        X = np.asarray(world, float).reshape(-1, 3)
        clip = (
            np.c_[X, np.ones(len(X))] @ np.array(self.rv3d.perspective_matrix).T
        )  # as location_3d_to_region_2d
        w = np.where(clip[:, 3] > 0, clip[:, 3], np.nan)
        half = np.array([self.region.width, self.region.height]) / 2
        region_xy = half + half * clip[:, :2] / w[:, None]
        return np.c_[self.region.x + region_xy[:, 0], self.window.height - (self.region.y + region_xy[:, 1])]

    def to_screen(self, region_xy) -> tuple[float, float]:
        """Region coordinates (from its bottom left) as screen pixels (from the window's top left)."""
        x, y = region_xy
        return self.region.x + x, self.window.height - (self.region.y + y)

    def centre(self) -> tuple[float, float]:
        return self.to_screen((self.region.width / 2, self.region.height / 2))

    def visible(self, world, tolerance: float) -> np.ndarray:
        """(k,) bool: whether each world point is the first thing the view ray through it meets."""
        depsgraph = bpy.context.evaluated_depsgraph_get()
        scene = bpy.context.scene
        flags = []
        for co in np.asarray(world, float).reshape(-1, 3):
            xy = view3d_utils.location_3d_to_region_2d(self.region, self.rv3d, co)
            if xy is None:
                flags.append(False)
                continue
            origin = view3d_utils.region_2d_to_origin_3d(self.region, self.rv3d, xy)
            direction = view3d_utils.region_2d_to_vector_3d(self.region, self.rv3d, xy)
            hit, location, *_ = scene.ray_cast(depsgraph, origin, direction)
            flags.append(bool(hit) and (location - type(location)(co)).length < tolerance)
        return np.array(flags, bool)


class Session:
    """What a session script works with: the viewport, input, screenshots and a record of results."""

    def __init__(self, name: str):
        self.name = name
        self.results: dict = {"blender": bpy.app.version_string}
        self.shots: list[str] = []
        os.makedirs(os.path.join(FOLDER, "shots"), exist_ok=True)

    # ------------------------------------------------------------------ results

    def record(self, key: str, value) -> None:
        """Keep a JSON-ready value for the test to assert on."""
        self.results[key] = _plain(value)

    def reports(self) -> list[str]:
        """Every report so far, oldest first, as Blender's Info editor lists them ("Error: …", "Info: …").

        The operators' messages reach the status bar and the Info editor, not the console, so this turns
        the timeline into an Info editor for a moment and copies its reports."""
        view = self.view3d()
        area = min((a for a in view.window.screen.areas if a != view.area), key=lambda a: a.height)
        was = area.ui_type
        area.ui_type = "INFO"
        region = next(r for r in area.regions if r.type == "WINDOW")
        with bpy.context.temp_override(
            window=view.window, screen=view.window.screen, area=area, region=region
        ):
            bpy.ops.info.select_all(action="SELECT")
            bpy.ops.info.report_copy()
        area.ui_type = was
        return [line for line in bpy.context.window_manager.clipboard.splitlines() if line.strip()]

    # ------------------------------------------------------------------ the window

    def view3d(self) -> View:
        window = bpy.context.window_manager.windows[0]
        areas = [a for a in window.screen.areas if a.type == "VIEW_3D"]
        if not areas:
            raise RuntimeError("the window has no 3D viewport")
        area = max(areas, key=lambda a: a.width * a.height)
        region = next(r for r in area.regions if r.type == "WINDOW")
        return View(window, area, region, area.spaces.active.region_3d)

    def region(self, view: View, kind: str) -> bpy.types.Region:
        """Another region of the viewport's area ('UI' is the sidebar, 'HEADER', 'TOOLS')."""
        return next(r for r in view.area.regions if r.type == kind)

    def redraw(self) -> None:
        for window in bpy.context.window_manager.windows:
            for area in window.screen.areas:
                area.tag_redraw()

    # ------------------------------------------------------------------ input (xdotool)

    def xdotool(self, *args) -> None:
        subprocess.run(["xdotool", *[str(a) for a in args]], check=True)

    def move(self, x: float, y: float, settle: float = 0.15):
        """Move the pointer there (twice: the first event after a jump is sometimes lost)."""
        self.xdotool("mousemove", round(x), round(y))
        yield settle
        self.xdotool("mousemove", round(x) + 1, round(y))
        yield 0.05
        self.xdotool("mousemove", round(x), round(y))
        yield settle

    def key(self, combo: str, settle: float = 0.4):
        """Press and release a key combination, e.g. 'ctrl+shift+e', 'Escape', 'f'."""
        self.xdotool("key", "--clearmodifiers", combo)
        yield settle

    def drag(self, points, button: int = 1, modifiers: tuple[str, ...] = (), step: float = 0.04):
        """Press a mouse button at the first point, move through the others, release at the last."""
        points = [(round(x), round(y)) for x, y in points]
        yield from self.move(*points[0])
        for modifier in modifiers:
            self.xdotool("keydown", modifier)
        yield 0.1
        self.xdotool("mousedown", button)
        yield 0.15
        for x, y in points[1:]:
            self.xdotool("mousemove", x, y)
            yield step
        yield 0.1
        self.xdotool("mouseup", button)
        yield 0.15
        for modifier in reversed(modifiers):
            self.xdotool("keyup", modifier)
        yield 0.3

    # ------------------------------------------------------------------ screenshots

    def shot(self, name: str, settle: float = 0.6):
        """Redraw, wait, and save the whole screen as shots/<name>.png."""
        self.redraw()
        yield settle
        path = os.path.join(FOLDER, "shots", f"{name}.png")
        subprocess.run(["import", "-window", "root", path], check=True)
        self.shots.append(name)
        yield 0.05

    # ------------------------------------------------------------------ the end

    def finish(self, error: str | None = None) -> None:
        if error:
            self.results["session_error"] = error
        self.results["shots"] = self.shots
        path = os.path.join(FOLDER, "results.json")
        with open(path + ".part", "w", encoding="utf-8") as out:
            json.dump(self.results, out, indent=1, default=repr)
        os.replace(path + ".part", path)
        sys.stdout.flush()
        sys.stderr.flush()
        bpy.ops.wm.quit_blender()


def _plain(value):
    """numpy values as JSON-ready Python ones."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)) or type(value).__module__ == "mathutils":
        return [_plain(v) for v in value]
    return value


def start(module: str, first_delay: float = 2.0) -> None:
    """Run ``steps`` of the session module ``module`` on Blender's timers."""
    session = Session(module)
    try:
        steps = importlib.import_module(module).steps(session)
    except Exception:
        session.finish(traceback.format_exc())
        return
    began = time.monotonic()

    def tick():
        try:
            delay = next(steps)
        except StopIteration:
            session.results["seconds"] = time.monotonic() - began
            session.finish()
            return None
        except Exception:
            session.finish(traceback.format_exc())
            return None
        return max(float(delay or 0.0), 0.01)

    bpy.app.timers.register(tick, first_interval=first_delay)
