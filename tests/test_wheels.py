"""The extension as users get it: the built zip installed into Pythons that hold only bpy (Blender 4.2 LTS
on Python 3.11 with NumPy 1.26, and the newest bpy on Python 3.13), so that its bundled wheels are the
only copy of our dependencies. A scripted session there paints, transfers and solves without a single
warning, every dependency imported from the extension's own folder, matplotlib never imported, and
retargets the solved grasp onto the alien hand in a child process (its workers too import the bundled
wheels); and that Blender's default keymap leaves our hotkeys alone."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from contact_edit_addon.commands import build
from contact_edit_addon.ui import keymaps

from . import bpy_only, hotkeys

pytestmark = pytest.mark.slow
#: The DeprecationWarnings SWIG < 4.3 bindings raise on Python 3.12+ (NLopt's, up to 2.11 at least).
SWIG = re.compile(r"DeprecationWarning: builtin type (Swig\w+|swigvarlink) has no __module__ attribute")

SESSION = """
import json, sys, warnings
caught = []
warnings.simplefilter("always")
warnings.showwarning = lambda message, category, filename, lineno, file=None, line=None: caught.append(
    f"{category.__name__}: {message} ({filename}:{lineno})")
import bpy
installed = bpy.ops.extensions.package_install_files(
    filepath=ZIP, repo="user_default", enable_on_install=True)
import geodesics, nlopt, numpy, potpourri3d, scipy, serial, solver, tangible
modules = {m.__name__: m.__file__ for m in (geodesics, nlopt, potpourri3d, scipy, serial, solver, tangible)}

bpy.ops.contact_edit.add_example()
scene = bpy.context.scene
hand, mug = scene.contact_edit.hand, scene.contact_edit.target
bpy.context.view_layer.objects.active = hand
import numpy as np
co = np.array([v.co for v in hand.data.vertices])
tip = co[np.argmax(co[:, 1])]
pad = (co[:, 1] > tip[1] - 0.02) & (np.abs(co[:, 0] - tip[0]) < 0.01) & (co[:, 2] < np.median(co[:, 2]))
hand.data.vertices.foreach_set("select", pad)
painted = bpy.ops.contact_edit.paint(name="tip", source="SELECTION")
from mathutils import Vector
wall = mug.matrix_world @ Vector((-0.04, 0.0, 0.06))  # the side facing the palm
transferred = bpy.ops.contact_edit.transfer(patch="tip", location=wall, direction=(0.0, 0.0, 1.0))
solved = bpy.ops.contact_edit.solve(stage="ALL", max_evaluations=6000)
from solver.ik import minimize  # as tests/test_solver_ik.py's optimizer failure, with the bundled NLopt
bounds = type("Bounds", (), {"lower": np.full(2, -10.0), "upper": np.full(2, 10.0)})
failure = minimize(lambda t: (float(t @ t), {}), lambda t: (float(t @ t), {}, np.full(2, np.nan)),
    np.array([1.0, 2.0]), np.arange(2), np.ones(2), bounds, "lbfgs")[4]
import time
from bl_ext.user_default.contact_edit import assets
from bl_ext.user_default.contact_edit.retarget import scene as scene_retarget
from solver.hands import make_hand
from solver.retarget.job import ChildRun
alien, alien_rig = assets.hand_objects(make_hand("alien"), "Alien", scene.collection)
reader, job, posed = scene_retarget.prepare(scene, hand, mug, alien, 1, 6, folder=FOLDER)
while reader.read_next():
    pass
reader.restore()
run = ChildRun(job, reader.motion(), workers=2)
began = time.monotonic()
while not run.done and time.monotonic() - began < 600:
    run.poll()
    time.sleep(0.05)
outcome = run.outcome()
action, _ = scene_retarget.commit(job, posed, outcome)
proposed = list(bpy.ops.contact_edit.annotation_propose(object_name=alien.name))
proposed_curves = [e.name for e in alien.contact_edit.annotation_patches if not e.marker]
print("RESULT " + json.dumps(dict(proposed=proposed, proposed_curves=proposed_curves,
    retargeted=outcome.summary(), action=action.name, keyed=alien_rig.animation_data.action == action,
    installed=list(installed), painted=list(painted), transferred=list(transferred), solved=list(solved),
    summary=scene.contact_edit.last_solve, failure=failure, modules=modules, numpy=numpy.__version__,
    scipy=scipy.__version__,
    blender=bpy.app.version_string, python=sys.version.split()[0], warnings=caught,
    site=[p for p in sys.path if "extensions" in p and p.endswith("site-packages")],
    matplotlib=[m for m in sys.modules if m.startswith("matplotlib")])))
"""


@pytest.fixture(scope="module")
def extension(tmp_path_factory) -> Path:
    return build.build_extension(tmp_path_factory.mktemp("dist"), platforms=["linux-x64"])[0]


@pytest.fixture(scope="module", params=sorted(bpy_only.ENVIRONMENTS))
def bpy_python(request) -> Path:
    try:
        return bpy_only.python(request.param)
    except RuntimeError as err:
        pytest.skip(str(err))


def run(python: Path, code: str, user: Path) -> tuple[dict, str]:
    env = {"PATH": os.environ["PATH"], "HOME": str(user), "BLENDER_USER_RESOURCES": str(user)}
    user.mkdir(parents=True, exist_ok=True)  # also the working folder, so our sources are not on the path
    done = subprocess.run(
        [str(python), "-c", code], capture_output=True, text=True, env=env, cwd=user, timeout=900
    )
    lines = [line for line in done.stdout.splitlines() if line.startswith(("RESULT ", "KEYMAP "))]
    assert done.returncode == 0 and lines, (
        f"{python} failed ({done.returncode}):\n{done.stdout}\n{done.stderr}"
    )
    return json.loads(lines[-1].split(" ", 1)[1]), done.stderr


def test_the_extension_runs_on_its_bundled_wheels_alone_without_warnings(bpy_python, extension, tmp_path):
    given = f"ZIP = {str(extension)!r}\nFOLDER = {str(tmp_path / 'retarget')!r}\n"
    out, stderr = run(bpy_python, given + textwrap.dedent(SESSION), tmp_path)
    assert out["installed"] == ["FINISHED"]
    (site,) = out["site"]
    assert site.startswith(str(tmp_path))
    for name, path in out["modules"].items():
        assert path.startswith(site), f"{name} came from {path}, not the extension's wheels"
    assert out["painted"] == out["transferred"] == out["solved"] == ["FINISHED"]
    assert out["failure"] == "stopped"  # NLopt's generic failure, as its bundled release raises it
    assert "contacts in 1 patch pairs" in out["summary"] and out["summary"].endswith("converged")
    assert out["retargeted"].startswith("Retargeted 6 frames; contacts "), out["retargeted"]
    assert out["action"] == "Alien from Hand" and out["keyed"]
    # An annotation proposed from the alien's armature on the wheels alone.
    assert out["proposed"] == ["FINISHED"]
    assert out["proposed_curves"] == ["thumb", "index", "middle", "palm", "palm_across"]
    # Every warning Python can raise is shown, hidden ones too; the only ones are DeprecationWarnings
    # (hidden by default) that SWIG before 4.3 puts in NLopt's bindings on Python 3.12+.
    shown = [w for w in out["warnings"] + stderr.splitlines() if "Warning" in w and not SWIG.search(w)]
    assert shown == []
    assert out["matplotlib"] == []


@pytest.mark.parametrize("name", ["dev", *sorted(bpy_only.ENVIRONMENTS)])
def test_blenders_default_keymap_leaves_our_hotkeys_alone(name, tmp_path):
    """On every Blender here: 4.2 and the newest (bpy-only Pythons) and the dev venv's 5.0."""
    try:
        python = Path(sys.executable) if name == "dev" else bpy_only.python(name)
    except RuntimeError as err:
        pytest.skip(str(err))
    defaults, _ = run(python, hotkeys.DEFAULT_KEYMAP_SCRIPT, tmp_path)
    assert len(defaults) > 2000  # the whole default keymap
    ours = [
        ["3D View", idname, key, *(m in mods for m in ("ctrl", "shift", "alt"))]
        for idname, key, mods, _ in keymaps.HOTKEYS
    ]
    assert hotkeys.clashes(ours, defaults) == {}
