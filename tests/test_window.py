"""The add-on in a real Blender window (Debian's Blender under Xvfb, see tests/window/harness.py), driven
by real key presses and mouse drags: the panel, hotkeys and Blender's own keymap, the area brush, the
overlay on every shape the viewport shows, the live transfer preview, and a solve stopped and cancelled.

Each session runs once per Blender; its screenshots are copied to $CONTACT_EDIT_SHOTS/<suite>/<session>/
(default: pytest's temporary folder) and named in the test output when a test fails. Where no window can
be had here (not root, no chroot yet), the tests skip and say how to get one.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from contact_edit_addon.commands import build
from contact_edit_addon.ui import keymaps

from . import hotkeys
from .window import harness

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module", params=sorted(harness.SUITES))
def blender(request):
    try:
        found = harness.WindowBlender.find(request.param)
    except RuntimeError as err:
        pytest.skip(str(err))
    yield found
    found.cleanup()


@pytest.fixture(scope="module")
def extension(tmp_path_factory) -> Path:
    return build.build_extension(tmp_path_factory.mktemp("dist"), platforms=["linux-x64"])[0]


_runs: dict = {}


def session(blender, extension, name: str, tmp_path_factory, timeout: float = 300) -> harness.SessionRun:
    """The session's run in this Blender (run on first use), checked to have ended cleanly."""
    key = (blender.suite, name)
    if key not in _runs:
        shots = os.environ.get("CONTACT_EDIT_SHOTS")
        out = (
            Path(shots) / blender.suite / name
            if shots
            else tmp_path_factory.mktemp(f"{blender.suite}-{name}")
        )
        _runs[key] = blender.session(name, extension, out, timeout=timeout)
    run = _runs[key]
    where = f"(Blender {blender.version}; log and screenshots in {run.folder})"
    assert "session_error" not in run.results, f"{run.results['session_error']}\n{where}"
    assert run.returncode == 0, f"Blender exited with {run.returncode}\n{run.log[-3000:]}\n{where}"
    ours = [t for t in run.tracebacks() if "contact_edit" in t or "geodesics" in t or "solver" in t]
    assert not ours, f"tracebacks from the add-on:\n{ours[0]}\n{where}"
    return run


@pytest.fixture(scope="module")
def panel(blender, extension, tmp_path_factory):
    return session(blender, extension, "panel", tmp_path_factory)


@pytest.fixture(scope="module")
def brush(blender, extension, tmp_path_factory):
    return session(blender, extension, "brush", tmp_path_factory)


@pytest.fixture(scope="module")
def transfer(blender, extension, tmp_path_factory):
    return session(blender, extension, "transfer", tmp_path_factory)


def pixels(run: harness.SessionRun, shot: str) -> np.ndarray:
    return np.asarray(Image.open(run.shots[shot]).convert("RGB")).astype(int)


def clear_of_axis(drawn: dict, margin: float = 4.0) -> np.ndarray:
    """(k,) bool: the patch points the view sees that its axis line and end markers do not cover."""
    xy, axis = np.array(drawn["xy"]), np.array(drawn["axis"])
    a, b = axis[:-1], axis[1:]
    t = np.clip(
        np.einsum("kjd,jd->kj", xy[:, None] - a, b - a) / np.maximum(((b - a) ** 2).sum(1), 1e-9), 0, 1
    )
    to_line = np.linalg.norm(xy[:, None] - (a + t[..., None] * (b - a)), axis=2).min(axis=1)
    to_ends = np.linalg.norm(xy[:, None] - axis[[0, -1]], axis=2).min(axis=1)
    return np.array(drawn["visible"]) & (to_line > margin) & (to_ends > 10)


def showing(image: np.ndarray, xy, color, tolerance: int = 24, reach: int = 1) -> np.ndarray:
    """(k,) bool: whether a pixel of ``color`` (0..1 RGB) lies within ``reach`` pixels of each point."""
    target = np.round(np.asarray(color[:3]) * 255)
    close = np.all(np.abs(image - target) <= tolerance, axis=2)
    found = np.zeros(len(xy), bool)
    height, width = close.shape
    for k, (x, y) in enumerate(np.round(np.asarray(xy)).astype(int)):
        if 0 <= x < width and 0 <= y < height:
            found[k] = close[max(y - reach, 0) : y + reach + 1, max(x - reach, 0) : x + reach + 1].any()
    return found


# ------------------------------------------------------------------------------------------ the panel


def test_hotkeys_pressed_too_early_say_why(panel):
    early = panel.results["early"]
    assert early[0].startswith("Choose the hand and the object")  # Ctrl+Shift+E, solve
    assert early[1].startswith("No device is connected")  # Ctrl+Shift+K, key the device pose
    assert early[2].startswith("Choose the hand and the object")  # Shift+Alt+T, transfer


def test_the_example_frames_a_hand_beside_a_mug(panel):
    x, y, width, height = panel.results["viewport"]
    boxes = {name: np.array(corners) for name, corners in panel.results["example"].items()}
    for name, box in boxes.items():
        assert np.all(
            (box[:, 0] > x) & (box[:, 0] < x + width) & (box[:, 1] > y) & (box[:, 1] < y + height)
        ), name
    span = np.ptp(np.concatenate(list(boxes.values())), axis=0)
    assert span[0] > 0.4 * width or span[1] > 0.4 * height  # framed, not a speck at the cursor
    hand, mug = boxes["Hand"], boxes["Mug"]
    assert np.ptp(hand[:, 0]) > 1.5 * np.ptp(mug[:, 0])  # the hand is hand-sized beside the mug


def test_the_sidebar_has_the_contact_tab(panel):
    assert panel.results["categories"][-1] == "Contact"
    assert "panel" in panel.shots and "add_menu" in panel.shots


def test_choosing_the_hand_says_at_once_how_its_rig_is_solved(panel):
    ok, *lines = panel.results["rig"]  # drawn in the Rig sub-panel (its draw raised nothing: see session)
    assert ok and lines[0] == "Wrist: hand" and lines[1] == "forearm moves and turns the hand"


def test_no_hotkey_of_ours_is_one_blender_already_uses_where_ours_would_run(panel):
    """Read from the running Blender's default keyconfig: a mode's keymap comes before the 3D View one,
    so a default hotkey there would silently win over ours."""
    ours = panel.results["our_keymap"]
    assert {(idname, key) for _, idname, key, *_ in ours} == {(i, k) for i, k, _, _ in keymaps.HOTKEYS}
    assert {keymap for keymap, *_ in ours} == {"3D View"}
    assert hotkeys.clashes(ours, panel.results["default_keymap"]) == {}


# ------------------------------------------------------------------------------------------ the brush


def test_the_brush_shows_its_circle_and_f_resizes_it(brush):
    results = brush.results
    assert results["radius_after"] > results["radius_before"] + 10
    x, y = results["stroke"][0]
    x += 2
    image = pixels(brush, "brush_circle")
    angles = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    radius = results["radius_before"]
    ring = np.c_[x + radius * np.cos(angles), y + radius * np.sin(angles)]
    assert showing(image, ring, (1.0, 1.0, 1.0), tolerance=40).mean() > 0.8
    inside = np.c_[x + 0.5 * radius * np.cos(angles), y + 0.5 * radius * np.sin(angles)]
    assert showing(image, inside, (1.0, 1.0, 1.0), tolerance=40, reach=0).mean() < 0.2


def test_a_stroke_paints_an_area_shift_adds_and_ctrl_takes_away(brush):
    (_, painted), (_, added), (_, subtracted) = (
        brush.results[k][0] for k in ("painted", "added", "subtracted")
    )
    assert painted > 50  # an area, not a one-sample line of points
    assert added > painted + 30
    assert 0 < subtracted < added - 30
    assert [len(brush.results[k]) for k in ("painted", "added", "subtracted")] == [1, 1, 1]


def test_painting_returns_to_blender_while_the_patch_is_made_and_esc_stops_it(brush):
    """The stroke's patch (its default axis, made to take 2 s here, and the parameterization) is made off
    the main thread: Blender's event loop keeps running (its timers, every 20 ms, are never held back
    long), the patch arrives later as one operator call, and Esc while it is made leaves nothing."""
    results = brush.results
    assert results["stopped"]["patches"] == []
    assert "Stopped making a patch of" in results["stopped"]["reports"][0]
    assert results["while_working"] == 0  # the stroke has ended and the patch is still being made
    wait = results["wait"]
    assert wait["seconds"] > 0.5  # it came later: the slowed axis takes 2 s from the release
    assert wait["longest_gap"] < 0.5  # a main thread blocked by the work would hold the timers 2 s
    assert results["last_operator"] == "CONTACT_EDIT_OT_paint"
    assert [len(results["painted"])] == [1]
    # A Shift stroke whose patch was changed (its axis reset) while the addition was worked out.
    stale = results["stale"]
    assert stale["patches"] == stale["painted"]  # the axis changed, the points did not
    assert "changed while adding" in stale["reports"][0] and "nothing was stored" in stale["reports"][0]


def test_the_patch_list_shows_a_new_patch_at_once(brush):
    """Blender redraws a panel when a property it shows is set, not when a script rebuilds a list: the
    new patch's colour swatch must be in the sidebar right after the stroke, with no mouse over it."""
    x, y, width, height = brush.results["sidebar"]
    linear = np.array(brush.results["color"][:3])  # a COLOR property: the swatch shows it in sRGB
    srgb = np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * linear ** (1 / 2.4) - 0.055)

    def swatch(shot):
        region = pixels(brush, shot)[y : y + height, x : x + width]
        return int(np.all(np.abs(region - np.round(srgb * 255)) <= 12, axis=2).sum())

    assert brush.results["categories"][-1] == "Contact"
    assert swatch("brush_circle") == 0
    assert swatch("sidebar_after_stroke") > 50


def test_the_overlay_draws_every_visible_point_on_the_surface_without_z_fighting(brush):
    drawn = brush.results["overlay"]
    color = brush.results["color"]
    clear = clear_of_axis(drawn)
    xy = np.array(drawn["xy"])[clear]
    assert clear.sum() > 50
    assert showing(pixels(brush, "overlay"), xy, color).mean() > 0.97
    assert showing(pixels(brush, "overlay_hidden"), xy, color).mean() < 0.05  # the control: hidden


def test_the_axis_start_is_a_large_white_marker(brush):
    x, y = np.round(brush.results["overlay"]["axis"][0]).astype(int)
    box = pixels(brush, "overlay")[y - 6 : y + 7, x - 6 : x + 7]
    white = np.all(box > 235, axis=2).sum()
    assert white >= 60  # a 13-pixel marker (points and the 2-pixel axis line are smaller)
    hidden = pixels(brush, "overlay_hidden")[y - 6 : y + 7, x - 6 : x + 7]
    assert np.all(hidden > 235, axis=2).sum() < 10


def test_a_round_pad_painted_with_the_bone_axis_has_its_axis_along_the_finger(brush):
    """One click of the brush on the middle fingertip with *Along the bone* chosen: along the pad (in
    the plane that fits it), the axis runs from the pad's back towards the fingertip as the bone under it
    does (the farthest points of a round pad lie anywhere around its rim)."""
    r = brush.results["bone_axis"]
    axis, finger, points = np.array(r["axis"]), np.array(r["finger"]), np.array(r["points"])
    normal = np.linalg.svd(points - points.mean(0))[2][2]
    chord, finger = (v - (v @ normal) * normal for v in (axis[-1] - axis[0], finger))
    assert len(points) > 20 and np.linalg.norm(chord) > 2e-3  # a pad, its axis across it
    assert chord @ finger > np.cos(np.radians(20)) * np.linalg.norm(chord) * np.linalg.norm(finger)
    assert "bone_axis" in brush.shots


def test_the_overlay_follows_the_pose_and_in_edit_mode_the_cage(brush):
    color = brush.results["color"]
    posed, cage = brush.results["posed"], brush.results["cage"]
    clear = clear_of_axis(posed)
    assert showing(pixels(brush, "posed"), np.array(posed["xy"])[clear], color).mean() > 0.95
    in_edit = pixels(brush, "edit_mode")
    clear = clear_of_axis(cage)
    assert showing(in_edit, np.array(cage["xy"])[clear], color).mean() > 0.95
    moved = np.linalg.norm(np.array(posed["xy"]) - np.array(cage["xy"]), axis=1) > 8
    assert moved.sum() > 20  # the pose moved the patch on screen, so the two places are told apart
    assert showing(in_edit, np.array(posed["xy"])[moved], color).mean() < 0.2


# ------------------------------------------------------------------------------------- transfer and solve


def test_the_transfer_is_previewed_under_the_mouse_then_stored_and_paired(transfer):
    results = transfer.results
    ((name, count),) = results["hand_patches"]
    assert results["mug_before"] == [] and results["mug_after"] == [[name, count]]
    assert results["paired"] == [[name, name]]
    box = np.array(results["mug_box"])
    (x0, y0), (x1, y1) = np.floor(box.min(0)).astype(int), np.ceil(box.max(0)).astype(int)
    blue = (0.15, 0.60, 0.95)  # the first patch colour

    def coloured(shot):
        region = pixels(transfer, shot)[y0:y1, x0:x1]
        return int(np.all(np.abs(region - np.round(np.array(blue) * 255)) <= 24, axis=2).sum())

    assert coloured("transfer_before") < 20
    assert coloured("transfer_hover") > 100  # the preview, before anything was stored
    assert coloured("transferred") > 100


def test_move_acts_on_the_patch_under_the_cursor_and_keeps_the_grab_offset(transfer):
    """Issue 37: with the hand active, Shift+Alt+M aimed at the mug's copy moved the hand's own pad, and
    the patch's axis start jumped to the cursor. Now the copy under the cursor moves, by what the cursor
    moved over the mug, not to the cursor (held well away from its axis start, on a smooth part)."""
    move = transfer.results["move"]
    assert move["hand_unchanged"] and move["active"] == move["hand"]
    assert move["mug_active_patch"] == transfer.results["hand_patches"][0][0]
    assert move["cursor_moved"] > 1e-3 and move["held_from_start"] > 0.3 * move["patch_length"]
    # moved by the cursor's move, taken to the surface at its axis start (which faces another way)
    assert 0.3 < move["start_moved"] / move["cursor_moved"] < 1.5
    assert move["start_from_cursor"] > 0.5 * move["held_from_start"]  # not to the cursor


def test_a_solve_shows_its_progress_esc_keeps_the_best_pose_and_right_click_puts_it_back(transfer):
    results = transfer.results
    assert results["first_pose_after"] < 5.0  # software OpenGL on two busy cores
    assert results["finished"].endswith(("converged", "stopped at the evaluation limit"))
    assert results["after_escape"].endswith("stopped by you; kept the best pose")
    assert results["moved_by_escape"] > 0
    assert results["cancel_restored"]
    # the panel still says how the last solve left the pose, which the cancel puts back (issue 37)
    assert results["after_cancel"] == results["after_escape"]
    reports = results["reports"]
    assert reports[-2] == results["after_escape"]
    assert reports[-1] == "Cancelled; the pose is as it was before the solve"
    assert "solving" in transfer.shots


@pytest.fixture(scope="module")
def grasp(blender, extension, tmp_path_factory):
    if blender.suite != "trixie":  # 5.2 runs the same session on the imported-style Example (CI time)
        pytest.skip("the Example's grasp runs in Blender 4.3's window; 5.2 runs it on the FBX-style Example")
    return session(blender, extension, "grasp", tmp_path_factory)


def test_a_grasp_painted_and_placed_by_eye_touches_and_a_turned_patch_keeps_the_hand(grasp):
    """Issue 41's session: the Example, four pads painted by dragging the brush (index and middle tips,
    thumb tip, palm), each transferred by press and drag a few millimetres and degrees off where a grasp
    known to exist puts it, then the solve's hotkey from the open hand: every pad touches, in seconds.
    Then the middle tip's patch turned 45° with the rotate tool and solved again: the hand keeps its
    orientation (within 30°) and the other pads their touch."""
    results = grasp.results
    assert [name for name, points in results["painted"]] == ["index tip", "middle tip", "thumb tip", "palm"]
    assert all(points > 30 for _, points in results["painted"])
    assert results["intended"] == ["index tip", "middle tip", "palm", "thumb tip"]
    assert all(pair == name for name, pair in results["paired"])
    for name, (off, turned) in results["misplaced"].items():  # by eye: near, not on, the grasp's spot
        assert 1.0 < off < 5.0 and turned < 20.0, name
    first = results["first"]
    assert sorted(first["touching"]) == sorted(results["intended"]), first["summary"]
    assert "all 4 patches touch" in first["summary"]
    assert first["deepest"] < 0.5e-3
    assert float(re.search(r"in ([0-9.]+) s", first["summary"])[1]) < 10.0  # software GL, two busy cores
    assert results["turned"][0] == "CONTACT_EDIT_OT_rotate" and abs(results["turned"][1] - 45.0) < 3.0
    second = results["second"]
    assert results["second_turn"] < 30.0, second["summary"]
    assert {"index tip", "thumb tip", "palm"} <= set(second["touching"]), second["summary"]
    assert {"placed", "solved", "solved_again"} <= set(grasp.shots)


@pytest.fixture(scope="module")
def grasp_imported(blender, extension, tmp_path_factory):
    if blender.suite != "sid":  # 4.3 runs the same session on the Example as added (CI time)
        pytest.skip("the FBX-style grasp runs in Blender 5.2's window; 4.3 runs it on the Example as added")
    return session(blender, extension, "grasp_imported", tmp_path_factory)


def test_the_grasp_on_an_fbx_style_subdivided_hand_touches_as_on_the_example(grasp_imported):
    """Issue 36's window case: the same session on the Example as Blender's FBX importer brings a hand
    (armature turned 90° and scaled 0.01, bones and mesh in centimetres) with a Subdivision Surface after
    the Armature modifier. The brush paints on the subdivided skin, the transfers keep true size, every
    pad touches, and the turned patch's re-solve keeps the hand."""
    results = grasp_imported.results
    assert [name for name, points in results["painted"]] == ["index tip", "middle tip", "thumb tip", "palm"]
    assert all(points > 30 for _, points in results["painted"])
    for name, (off, turned) in results["misplaced"].items():
        assert 1.0 < off < 5.0 and turned < 20.0, name
    first = results["first"]
    # the subdivided skin's pads press deeper than the Example's (0.7 mm here, 34 um there); pressing keeps
    # every skin within PRESS_DEPTH (0.95 mm on this hand), the benchmark's bar is 1 mm
    assert "all 4 patches touch" in first["summary"] and first["deepest"] < 1e-3, first["summary"]
    assert "from the solved pose" not in first["summary"]
    assert results["second_turn"] < 30.0, results["second"]["summary"]
    assert {"index tip", "thumb tip", "palm"} <= set(results["second"]["touching"])


# ------------------------------------------------------------------------------------- the puppet device


@pytest.fixture(scope="module")
def device(blender, extension, tmp_path_factory):
    return session(blender, extension, "device", tmp_path_factory)


def test_the_status_bar_says_what_the_device_panel_says(device):
    results = device.results
    assert results["status"].startswith("Connected to the simulator: 3 joints attached")
    shown = [
        r for r in results["reports"] if r.startswith(("Connected", "Live", "Joint", "Lost", "The device on"))
    ]
    assert shown[-1] == results["status"]  # the latest device report is the panel's line
    assert results["reports"][-1].startswith("The device poses nothing yet")  # Ctrl+Shift+K, no bindings
    assert results["stopped"].startswith("Stopped")


@pytest.fixture(scope="module")
def retargeting(blender, extension, tmp_path_factory):
    return session(blender, extension, "retarget", tmp_path_factory, timeout=600)  # a minute's solves, twice


def test_retargeting_keeps_blender_running_esc_keeps_frames_and_again_goes_on(retargeting):
    """A retarget of the example's grasp onto the alien hand, from the Retarget settings: the operator holds
    Blender up for a moment at a time only (its invoke reads the rigs; each timer tick reads frames for
    40 ms or polls the child process), so the event loop runs all along where a synchronous retarget would
    hold it for the whole minute; Esc stops it with nothing changed but the solved frames kept, and
    Retarget again solves only the rest and keys the action, which Ctrl+Z takes back in one step. The
    procedural hands its check compares with were made before, on timer ticks after start-up.

    The 20 ms heartbeat timers wait longer than the operator's calls: Blender redraws the window between
    ticks by software OpenGL here (a third of a second, measured), and while the child process and its
    workers start they take both cores."""
    r = retargeting.results
    assert r["made_before_retarget"] == ["alien", "human", "tentacle", "witch"]  # on ticks after start-up
    assert r["longest_invoke"][1] < 0.5, r["longest_invoke"]
    assert r["longest_modal"][1] < 0.15, r["longest_modal"]
    assert r["modal_calls"] > 50  # the ticks went on while the child worked
    for phase in ("reading", "stopping", "run"):
        assert r[phase]["longest_gap"] < 1.0, (phase, r[phase])
    assert r["stopping"]["seconds"] < 30
    assert "A retarget is running: wait for it, or press Esc to stop it" in r["second"]  # one at a time
    assert r["after_escape"].startswith("Stopped; nothing changed") and "kept in" in r["after_escape"]
    assert not r["action_after_escape"]
    assert len(r["kept"]) >= 2
    assert r["frame_after_escape"] == 1  # the frames were read and the scene put back where it was
    assert r["last"].startswith("Retargeted 16 frames; contacts "), r["last"]
    assert r["resolved"] == []  # the frames kept were not solved again
    assert r["action"] == "Alien from Hand"
    assert any("Retargeted 16 frames" in line for line in r["reports"])
    assert "panel" in retargeting.shots  # the Retarget panel drawn open, its draw raising nothing
    assert r["undone"] and "Alien from Hand" not in r["actions_after_undo"]  # Ctrl+Z: one step back


@pytest.fixture(scope="module")
def annotating(blender, extension, tmp_path_factory):
    return session(blender, extension, "annotation", tmp_path_factory)


def _changed_pixels(a: Path, b: Path) -> int:
    """Pixels of the viewport's middle (the hand; not the sidebar, the status bar or the redo panel) that
    differ between two screenshots."""
    A, B = (np.asarray(Image.open(p).convert("RGB"), dtype=np.int16) for p in (a, b))
    h, w = A.shape[:2]
    middle = (slice(int(0.1 * h), int(0.85 * h)), slice(int(0.05 * w), int(0.6 * w)))
    return int((np.abs(A[middle] - B[middle]).max(axis=2) > 40).sum())


def test_proposing_an_annotation_keeps_blender_running_shows_it_and_undoes_in_one_step(annotating):
    """Propose on the example hand: its curves and markers are made in a worker thread (no call of the
    operator holds Blender up for long), the tools switch to the annotation, the viewport draws it instead
    of the contacts (and the contacts again when switched back), the panels draw without error, and
    Ctrl+Z takes it all back."""
    r = annotating.results
    assert r["proposing"]["longest_gap"] < 1.0, r["proposing"]
    assert max(call[1] for call in r["calls"]) < 0.3, r["calls"]
    assert r["layer"] == "ANNOTATION"
    names = [name for name, _, _ in r["entries"]]
    assert names[:7] == ["thumb", "index", "middle", "ring", "pinky", "palm", "palm_across"]
    assert all(girth > 0 for _, marker, girth in r["entries"] if not marker)
    assert sum(marker for _, marker, _ in r["entries"]) == 19
    assert any(line.startswith("Proposed on 'Hand'") for line in r["reports"]), r["reports"]
    shots = annotating.shots
    assert _changed_pixels(shots["contacts"], shots["annotation"]) > 500  # the annotation is drawn
    assert (
        _changed_pixels(shots["contacts"], shots["contacts again"]) < 50
    )  # the contacts again, as they were
    assert _changed_pixels(shots["annotation"], shots["annotation again"]) < 50
    assert "panel" in shots
    assert r["after_undo"] == 0
