"""Running scripts in the real bpy module, each in a fresh process with its own temporary Blender user
folder (so tests never touch a real user's configuration). Scripts report with ``result(value)`` and
may use ``keyed_frames(obj)`` (the frames an object's action keys)."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

PRELUDE = """
import json, sys
import bpy
def result(value):
    print("RESULT " + json.dumps(value))
def keyed_frames(obj):
    from bpy_extras import anim_utils
    data = obj.animation_data
    if data is None or data.action is None:
        return []
    bag = anim_utils.action_get_channelbag_for_slot(data.action, data.action_slot)
    return sorted({k.co[0] for curve in bag.fcurves for k in curve.keyframe_points})
"""


#: The ``contact-edit`` console script, run by this Python (the dev venv's, with its packages).
CONTACT_EDIT = (
    sys.executable,
    "-c",
    "import sys; from contact_edit_addon.commands.cli import main; sys.exit(main())",
)


def fresh_process(args, *, user_dir: Path, cwd: Path | None = None, timeout: float = 1800):
    """``args`` run in a fresh process (real file descriptors, output captured as text) with its own
    Blender user folder. Output is buffered as for most users (no ``PYTHONUNBUFFERED``)."""
    env = {**os.environ, "BLENDER_USER_RESOURCES": str(user_dir)}
    env.pop("PYTHONUNBUFFERED", None)
    return subprocess.run(list(args), capture_output=True, text=True, cwd=cwd, env=env, timeout=timeout)


def contact_edit(*args: str, cwd: Path, user_dir: Path) -> subprocess.CompletedProcess:
    """``contact-edit ARGS`` in a fresh process (:func:`fresh_process`)."""
    return fresh_process([*CONTACT_EDIT, *args], user_dir=user_dir, cwd=cwd)


def run_blender(script: str, user_dir: Path, setup: str = "", timeout: float = 300) -> dict:
    """Run ``setup`` then ``script`` with bpy; the script reports by calling ``result(value)``. Raises with
    the output on failure; skips the test where bpy is not installed."""
    if importlib.util.find_spec("bpy") is None:
        pytest.skip("needs bpy (the dev extra)")
    code = PRELUDE + textwrap.dedent(setup) + textwrap.dedent(script)
    done = fresh_process([sys.executable, "-c", code], user_dir=user_dir, timeout=timeout)
    lines = [line for line in done.stdout.splitlines() if line.startswith("RESULT ")]
    if done.returncode != 0 or not lines:
        raise AssertionError(f"Blender script failed ({done.returncode}):\n{done.stdout}\n{done.stderr}")
    return json.loads(lines[-1][len("RESULT ") :])
