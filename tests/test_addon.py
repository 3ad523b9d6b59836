"""The add-on in the real bpy 5.0.1 module: installing the built extension, and the contact tools driven
headless with explicit properties, as batch scripts use them."""

import re
from pathlib import Path

import numpy as np
import pytest

from contact_edit_addon.commands import build
from solver.hands import KINDS

from .blender import run_blender

SETUP = """
import numpy as np
import contact_edit_addon
contact_edit_addon.register()
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.mesh.primitive_grid_add(x_subdivisions=30, y_subdivisions=30, size=2.0)
hand = bpy.context.active_object
hand.name = "Hand"
bpy.ops.mesh.primitive_uv_sphere_add(radius=1.0, location=(0, 0, 3))
ball = bpy.context.active_object
ball.name = "Ball"
scene = bpy.context.scene
scene.contact_edit.hand, scene.contact_edit.target = hand, ball
bpy.context.view_layer.objects.active = hand

def select_disk(cx, cy, r):
    co = np.empty(3 * len(hand.data.vertices)); hand.data.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3)
    hand.data.vertices.foreach_set("select", np.hypot(co[:, 0] - cx, co[:, 1] - cy) < r)

from contact_edit_addon import store
"""


@pytest.fixture(scope="module")
def extension(tmp_path_factory) -> Path:
    return build.build_extension(tmp_path_factory.mktemp("dist"), platforms=["linux-x64"])[0]


def test_extension_validates_installs_enables_and_uninstalls(extension, tmp_path):
    out = run_blender(
        f"""
        import importlib.util, os, zipfile
        path = os.path.join(bpy.utils.system_resource("SCRIPTS"), "addons_core/bl_pkg/cli/blender_ext.py")
        spec = importlib.util.spec_from_file_location("blender_ext", path)
        blender_ext = importlib.util.module_from_spec(spec); spec.loader.exec_module(blender_ext)
        errors = blender_ext.pkg_manifest_from_zipfile_and_validate_all_errors(
            zipfile.ZipFile({str(extension)!r}), archive_subdir="", strict=True)
        installed = bpy.ops.extensions.package_install_files(
            filepath={str(extension)!r}, repo="user_default", enable_on_install=True)
        enabled = "bl_ext.user_default.contact_edit" in bpy.context.preferences.addons
        operators = hasattr(bpy.ops.contact_edit, "paint") and hasattr(bpy.types.Object, "contact_edit")
        site = os.path.join({str(tmp_path)!r}, "extensions/.local/lib/python3.11/site-packages")
        bundled = sorted(os.listdir(site))
        # The bundled NLopt (built against numpy 2) on Blender's numpy 1.x, imported from the bundle only.
        import subprocess, sys
        probe = "\\n".join([
            "import sys",
            "sys.path.insert(0, %r)" % site,
            "import numpy, nlopt",
            "assert nlopt.__file__.startswith(%r), nlopt.__file__" % site,
            "def f(x, grad):",
            "    if grad.size:",
            "        grad[:] = 2 * (x - 1)",
            "    return float(((x - 1) ** 2).sum())",
            "opt = nlopt.opt(nlopt.LD_SLSQP, 2)",
            "opt.set_lower_bounds([-1, -1]); opt.set_upper_bounds([1, 0.5])",
            "opt.set_min_objective(f); opt.set_ftol_rel(1e-12)",
            "print(nlopt.__version__, numpy.__version__, *opt.optimize([0.0, 0.0]))",
        ])
        nlopt_run = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True)
        # A whole contact solve through the installed extension's operators.
        bpy.ops.contact_edit.add_hand(kind="human")
        bpy.ops.contact_edit.add_object(shape="sphere")
        hand = bpy.context.scene.contact_edit.hand
        bpy.context.view_layer.objects.active = hand
        pads = [v.co.z < -0.005 and v.co.y > 0.17 for v in hand.data.vertices]
        hand.data.vertices.foreach_set("select", pads)
        bpy.ops.contact_edit.paint(name="tip", source="SELECTION")
        top = bpy.context.scene.contact_edit.target.location + __import__("mathutils").Vector((0, 0, 0.04))
        bpy.ops.contact_edit.transfer(patch="tip", location=top, direction=(0, 1, 0))
        solved = bpy.ops.contact_edit.solve(stage="ALL")
        summary = bpy.context.scene.contact_edit.last_solve
        repos = [r.module for r in bpy.context.preferences.extensions.repos]
        index = repos.index("user_default")
        removed = bpy.ops.extensions.package_uninstall(repo_index=index, pkg_id="contact_edit")
        left = os.path.join({str(tmp_path)!r}, "extensions/user_default/contact_edit")
        result(dict(errors=errors if isinstance(errors, list) else [], installed=list(installed),
                    enabled=enabled, operators=operators, bundled=bundled, removed=list(removed),
                    nlopt=[nlopt_run.returncode, nlopt_run.stdout, nlopt_run.stderr],
                    solved=list(solved), summary=summary,
                    still_enabled="bl_ext.user_default.contact_edit" in bpy.context.preferences.addons,
                    properties_left=hasattr(bpy.types.Object, "contact_edit"),
                    files_left=os.path.exists(left)))
        """,
        tmp_path,
    )
    assert out["errors"] == []
    assert out["installed"] == ["FINISHED"] and out["enabled"] and out["operators"]
    for package in ("geodesics", "solver", "tangible", "scipy", "potpourri3d", "serial", "nlopt"):
        assert package in out["bundled"]
    code, printed, errors = out["nlopt"]
    assert code == 0, errors
    version, numpy, *x = printed.split()
    assert (version, numpy) == ("2.9.1", "1.26.4") and [float(v) for v in x] == pytest.approx([1.0, 0.5])
    assert out["solved"] == ["FINISHED"] and "contacts in 1 patch pairs" in out["summary"]
    assert "numpy" not in out["bundled"]  # Blender's own
    assert out["removed"] == ["FINISHED"]
    assert not out["still_enabled"] and not out["properties_left"] and not out["files_left"]


def test_contact_tools_run_headless_and_persist(tmp_path):
    out = run_blender(
        f"""
        select_disk(0.2, 0.1, 0.35)
        bpy.ops.contact_edit.paint(name="palm", source="SELECTION")
        select_disk(0.7, 0.1, 0.12)
        bpy.ops.contact_edit.paint(name="tip", source="SELECTION")
        bpy.ops.contact_edit.parent(child="tip", parent="palm")
        before = store.load(hand)
        bpy.ops.contact_edit.rotate(patch="palm", angle=0.3)
        bpy.ops.contact_edit.translate(patch="palm", location=(0.1, -0.1, 0.0))
        bpy.ops.contact_edit.bend(patch="palm", index=2, angle=0.2)
        after = store.load(hand)
        moved_tip = float(np.abs(after["tip"].positions() - before["tip"].positions()).max())
        bpy.ops.contact_edit.axis(patch="tip", method="MEDIAL")
        bpy.ops.contact_edit.transfer(patch="palm", location=(0, 0, 2.0), direction=(1, 0, 0), suffix="@ball")
        ball_patches = [(p.name, p.points, p.pair, p.parent) for p in ball.contact_edit.patches]
        hand_pairs = {{p.name: p.pair for p in hand.contact_edit.patches}}
        data = hand.contact_edit.data
        messages = []
        for call in (lambda: bpy.ops.contact_edit.translate(patch="palm", location=(5.0, 5.0, 0.0)),
                     lambda: bpy.ops.contact_edit.rotate(patch="nope", angle=0.1)):
            try:
                call()
            except RuntimeError as err:
                messages.append(str(err))
        unchanged = hand.contact_edit.data == data
        library = {str(tmp_path / "library.json")!r}
        bpy.ops.contact_edit.library_save(filepath=library)
        bpy.ops.contact_edit.clear(all=True)
        cleared = len(hand.contact_edit.patches)
        bpy.ops.contact_edit.library_load(filepath=library)
        reloaded = store.load(hand)
        same = float(np.abs(reloaded["palm"].positions() - store.load(hand)["palm"].positions()).max())
        bpy.ops.wm.save_as_mainfile(filepath={str(tmp_path / "scene.blend")!r})
        bpy.ops.wm.open_mainfile(filepath={str(tmp_path / "scene.blend")!r})
        persisted = [p.name for p in bpy.data.objects["Hand"].contact_edit.patches]
        persisted_ball = [p.name for p in bpy.data.objects["Ball"].contact_edit.patches]
        result(dict(moved_tip=moved_tip, ball=ball_patches, pairs=hand_pairs, messages=messages,
                    unchanged=unchanged, cleared=cleared, same=same, persisted=persisted,
                    persisted_ball=persisted_ball))
        """,
        tmp_path,
        setup=SETUP,
    )
    assert out["moved_tip"] > 0.01  # the child followed its parent
    assert [b[0] for b in out["ball"]] == ["palm@ball", "tip@ball"]
    assert out["ball"][1][3] == "palm@ball"  # the hierarchy came along
    assert out["pairs"] == {"palm": "palm@ball", "tip": "tip@ball"}
    # Moved 7 m across a 2 m plane: the axis or its points leave it first, as the default axis lies.
    assert re.search(r"(axis runs|patch points would fall) off the surface's boundary", out["messages"][0])
    assert "no patch named 'nope'" in out["messages"][1]
    assert out["unchanged"]
    assert out["cleared"] == 0 and out["same"] == 0.0
    assert out["persisted"] == ["palm", "tip"] and out["persisted_ball"] == ["palm@ball", "tip@ball"]


def test_a_name_edited_in_the_patch_list_renames_the_patch(tmp_path):
    """Typing a new name into the list renames the patch in its set: its child's parent and the pair
    recorded on the other object follow, the annotation's list renames its own patches, and a name
    another patch has is put back."""
    out = run_blender(
        """
        select_disk(0.2, 0.1, 0.35)
        bpy.ops.contact_edit.paint(name="palm", source="SELECTION")
        select_disk(0.7, 0.1, 0.12)
        bpy.ops.contact_edit.paint(name="tip", source="SELECTION")
        bpy.ops.contact_edit.parent(child="tip", parent="palm")
        bpy.ops.contact_edit.transfer(patch="palm", location=(0, 0, 2.0), direction=(1, 0, 0), suffix="@ball")
        store.entries(hand)["palm"].name = "heel"
        store.entries(hand)["tip"].name = "heel"  # taken
        hand.contact_edit.layer = "ANNOTATION"
        select_disk(-0.5, -0.5, 0.2)
        bpy.ops.contact_edit.paint(name="contact", source="SELECTION")
        store.entries(hand)["contact"].name = "index"
        contacts = store.load(hand, layer="CONTACTS")
        result(dict(hand=list(contacts), pairs=dict(contacts.pairs),
                    links={c: l.parent for c, l in contacts.links.items()},
                    entries=[(e.name, e.parent, e.pair) for e in store.entries(hand, "CONTACTS")],
                    ball_pairs=dict(store.load(ball, layer="CONTACTS").pairs),
                    ball_entries=[(e.name, e.pair) for e in store.entries(ball, "CONTACTS")],
                    annotation=list(store.load(hand, layer="ANNOTATION")),
                    annotation_entries=[e.name for e in store.entries(hand, "ANNOTATION")]))
        """,
        tmp_path,
        setup=SETUP,
    )
    assert out["hand"] == ["heel", "tip"] and out["links"] == {"tip": "heel"}
    assert out["pairs"] == {"heel": "palm@ball", "tip": "tip@ball"}
    assert out["entries"] == [["heel", "", "palm@ball"], ["tip", "heel", "tip@ball"]]
    assert out["ball_pairs"] == {"palm@ball": "heel", "tip@ball": "tip"}
    assert out["ball_entries"] == [["palm@ball", "heel"], ["tip@ball", "tip"]]
    assert out["annotation"] == out["annotation_entries"] == ["index"]


def test_a_pair_keeps_one_colour_through_transfers_in_any_order_and_edits(tmp_path):
    """Issue 37's case: paint ``contact`` then ``contact.001``, transfer the second first, then move and
    turn a copy on the ball. Each copy keeps its hand patch's colour (saving a list read its kept colours
    as views of the entries it then rebuilt, so every save swapped them by position), and a colour set in
    either list is its partner's too, through later edits."""
    out = run_blender(
        """
        select_disk(0.2, 0.1, 0.25)
        bpy.ops.contact_edit.paint(name="contact", source="SELECTION")
        select_disk(-0.4, -0.3, 0.2)
        bpy.ops.contact_edit.paint(name="contact.001", source="SELECTION")
        for patch, where in (("contact.001", (0, 0, 2.0)), ("contact", (0, 0.5, 2.1))):
            bpy.ops.contact_edit.transfer(patch=patch, location=where, direction=(1, 0, 0), suffix="@b")
        bpy.context.view_layer.objects.active = ball
        bpy.ops.contact_edit.translate(patch="contact@b", object_name="Ball", location=(0.1, 0.6, 2.1))
        bpy.ops.contact_edit.rotate(patch="contact.001@b", object_name="Ball", angle=0.4)
        def colours():
            return {e.name: [round(c, 4) for c in e.color]
                    for obj in (hand, ball) for e in store.entries(obj, "CONTACTS")}
        edited = colours()
        store.entries(ball, "CONTACTS")["contact@b"].color = (1.0, 0.0, 0.0, 1.0)
        bpy.ops.contact_edit.rotate(patch="contact.001@b", object_name="Ball", angle=-0.4)
        bpy.context.view_layer.objects.active = hand
        bpy.ops.contact_edit.rotate(patch="contact", object_name="Hand", angle=0.2)
        result(dict(edited=edited, picked=colours()))
        """,
        tmp_path,
        setup=SETUP,
    )
    edited, picked = out["edited"], out["picked"]
    assert edited["contact"] != edited["contact.001"]
    for name in ("contact", "contact.001"):
        assert edited[name] == edited[f"{name}@b"]
    assert picked["contact"] == picked["contact@b"] == [1.0, 0.0, 0.0, 1.0]
    assert picked["contact.001"] == picked["contact.001@b"] == edited["contact.001"]


def test_each_pose_button_has_its_own_tooltip(tmp_path):
    """Issue 37: Root, Fingers, All and Selected read the same tooltip, and so did Flex and Wrap: each
    now says what its stage frees or how it curls (Blender asks the operator's ``description``)."""
    out = run_blender(
        """
        from types import SimpleNamespace
        from contact_edit_addon import posing
        from contact_edit_addon.operators.solve import CONTACT_EDIT_OT_solve, CONTACT_EDIT_OT_flex_to_contact
        solve = {key: CONTACT_EDIT_OT_solve.description(bpy.context, SimpleNamespace(stage=key))
                 for key, _, _ in posing.STAGES}
        flex = {j: CONTACT_EDIT_OT_flex_to_contact.description(bpy.context, SimpleNamespace(joints=j))
                for j in ("TOGETHER", "IN_TURN")}
        result(dict(solve=solve, flex=flex, stages={key: text for key, _, text in posing.STAGES}))
        """,
        tmp_path,
        setup=SETUP,
    )
    assert len(set(out["solve"].values())) == 4 and len(set(out["flex"].values())) == 2
    for key, text in out["stages"].items():
        assert out["solve"][key].startswith("Pose the hand's armature so that its contact patches meet")
        assert out["solve"][key].endswith(f"on the object. {text}")
    assert "fingertips close first" in out["flex"]["TOGETHER"] and "wrap" in out["flex"]["IN_TURN"]


def test_brush_strokes_become_points_inside_faces(tmp_path):
    out = run_blender(
        """
        hits = []
        for x in np.linspace(-0.5, 0.5, 30):
            ok, location, normal, polygon = hand.ray_cast((x, 0.5, 1.0), (0, 0, -1))
            hits.append({"name": "", "location": location[:], "polygon": polygon, "radius": 0.0})
        bpy.ops.contact_edit.paint(name="stroke", source="STROKE", stroke=hits)
        patch = store.load(hand)["stroke"]
        X = patch.positions()
        result(dict(n=len(patch), y=[float(X[:, 1].min()), float(X[:, 1].max())],
                    x=[float(X[:, 0].min()), float(X[:, 0].max())]))
        """,
        tmp_path,
        setup=SETUP,
    )
    assert out["n"] == 30
    assert out["y"] == pytest.approx([0.5, 0.5], abs=1e-12)
    assert out["x"] == pytest.approx([-0.5, 0.5], abs=1e-12)


def test_the_area_brush_paints_adds_and_takes_away_at_the_scene_density(tmp_path):
    """Dabs of 10 cm along a line paint the stadium they cover at the density (1 point per cm² here);
    Shift adds, Ctrl takes away, a transferred patch follows its hand patch, a view from behind paints
    nothing, and the object's copy refuses to be painted on directly."""
    out = run_blender(
        """
        scene.contact_edit.brush_density = 1.0
        def dabs(y, x0=-0.5, x1=0.5, radius=0.1, n=41):
            items = []
            for x in np.linspace(x0, x1, n):
                ok, location, normal, polygon = hand.ray_cast((x, y, 1.0), (0, 0, -1))
                items.append({"name": "", "location": location[:], "polygon": polygon, "radius": radius})
            return items
        bpy.ops.contact_edit.paint(name="band", source="STROKE", stroke=dabs(0.2), eye=(0, 0, 2))
        X = store.load(hand)["band"].positions()
        to_line = np.hypot(np.maximum(np.abs(X[:, 0]) - 0.5, 0), X[:, 1] - 0.2)
        painted = len(X)
        bpy.ops.contact_edit.transfer(patch="band", location=(0, -0.3, 4.0), direction=(1, 0, 0))
        ball_axis = store.load(ball)["band"].axis.points.positions(store.load(ball).mesh)
        bpy.ops.contact_edit.paint(source="STROKE", mode="ADD", stroke=dabs(0.45, radius=0.05))
        added = len(store.load(hand)["band"])
        on_ball_added = len(store.load(ball)["band"])
        before = store.load(hand)["band"].positions()
        eraser = dabs(0.2, -0.1, 0.1, 0.05, 5)
        bpy.ops.contact_edit.paint(source="STROKE", mode="SUBTRACT", stroke=eraser)
        kept = store.load(hand)["band"]
        centres = np.array([d["location"] for d in eraser])
        reach = np.linalg.norm(before[:, None] - centres[None], axis=2).min(axis=1)
        on_ball = store.load(ball)["band"]
        messages = []
        for call in (
            lambda: bpy.ops.contact_edit.paint(source="STROKE", stroke=dabs(-0.4), eye=(0, 0, -2)),
            lambda: (setattr(bpy.context.view_layer.objects, "active", ball),
                     bpy.ops.contact_edit.paint(source="STROKE", mode="ADD", stroke=[
                         {"name": "", "location": (0, -0.3, 4.0), "polygon": 0, "radius": 0.2}])),
        ):
            try:
                call()
            except RuntimeError as err:
                messages.append(str(err))
        result(dict(painted=painted, far=float(to_line.max()), added=added, on_ball_added=on_ball_added,
                    kept=len(kept), expected=int((reach > 0.05).sum()), on_ball=len(on_ball),
                    kept_exactly=bool(np.array_equal(kept.positions(), before[reach > 0.05])),
                    axis_kept=float(np.abs(on_ball.axis.points.positions(on_ball.mesh) - ball_axis).max()),
                    messages=messages, names=[e.name for e in hand.contact_edit.patches]))
        """,
        tmp_path,
        setup=SETUP,
    )
    stadium = 1.0 * 0.2 + np.pi * 0.1**2  # m², at 10,000 points per m²
    assert out["painted"] == pytest.approx(stadium * 1e4, rel=0.04)
    assert out["far"] <= 0.1 + 1e-9
    assert out["added"] == pytest.approx(out["painted"] + (1.0 * 0.1 + np.pi * 0.05**2) * 1e4, rel=0.05)
    assert out["on_ball_added"] == out["added"]  # the transfer follows, point for point
    assert out["kept"] == out["expected"] < out["added"] and out["kept_exactly"]  # the eraser's balls
    assert out["on_ball"] == out["kept"] and out["axis_kept"] == 0.0  # it keeps its place
    assert "facing the view" in out["messages"][0]
    assert "transfer of the hand's patch 'band'" in out["messages"][1]
    assert out["names"] == ["band"]


def test_contacts_follow_a_changed_mesh_by_position(tmp_path):
    """Contacts stored for one topology are projected onto the surface when the mesh changes."""
    out = run_blender(
        """
        select_disk(0.2, 0.1, 0.3)
        bpy.ops.contact_edit.paint(name="palm", source="SELECTION")
        before = store.load(hand)["palm"].positions()
        import bmesh
        bm = bmesh.new(); bm.from_mesh(hand.data)
        bmesh.ops.subdivide_edges(bm, edges=[e for e in bm.edges if e.verts[0].co.x < -0.9], cuts=1)
        bm.to_mesh(hand.data); bm.free()
        after = store.load(hand)["palm"].positions()
        result(dict(gap=float(np.abs(after - before).max()), n=len(after)))
        """,
        tmp_path,
        setup=SETUP,
    )
    assert out["gap"] < 1e-9  # the surface did not move, so the contacts did not either


def test_a_mesh_carried_into_another_space_is_built_once_per_mesh_and_matrix(tmp_path):
    """Each solve carries the object's mesh into the armature's space; the carried mesh (and what is built
    for it, like its closest-point index) is kept while neither the mesh nor the matrix changes."""
    out = run_blender(
        """
        from contact_edit_addon import bridge
        mesh = bridge.trimesh(hand)
        M = np.eye(4); M[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]; M[:3, 3] = (0.1, 0.2, 0.3)
        first, again = bridge.moved(mesh, M), bridge.moved(mesh, M.copy())
        N = M.copy(); N[0, 3] += 1e-3
        other = bridge.moved(mesh, N)
        hand.data.vertices[0].co.z += 0.01
        changed = bridge.moved(bridge.trimesh(hand), M)
        result(dict(
            same=first is again, other=other is not first, changed=changed is not first,
            gap=float(np.abs(first.vertices - (mesh.vertices @ M[:3, :3].T + M[:3, 3])).max()),
            moved_by=float(np.abs(changed.vertices - first.vertices).max()),
        ))
        """,
        tmp_path,
        setup=SETUP,
    )
    assert out["same"] and out["other"] and out["changed"]
    assert out["gap"] == 0.0 and abs(out["moved_by"] - 0.01) < 1e-7  # Blender keeps float32 coordinates


def test_registering_freezes_the_sessions_objects_out_of_the_cycle_collector(tmp_path):
    """Registered, the add-on moves what Python tracks (Blender's, NumPy's and its own modules, functions
    and classes) out of the cycle collector's way, so that a full collection no longer walks them inside
    some tool's call; unregistered, it gives them back."""
    out = run_blender(
        """
        import gc
        import contact_edit_addon
        before = gc.get_freeze_count()
        contact_edit_addon.register()
        frozen, tracked = gc.get_freeze_count(), len(gc.get_objects())
        contact_edit_addon.unregister()
        result(dict(before=before, frozen=frozen, tracked=tracked, after=gc.get_freeze_count()))
        """,
        tmp_path,
    )
    assert out["before"] == 0 and out["after"] == 0
    assert out["frozen"] > 50_000 and out["tracked"] < 0.05 * out["frozen"], out


def test_after_start_up_timer_ticks_make_the_procedural_hands_one_each(tmp_path):
    """Registering starts a timer that makes the procedural hands Retarget checks its hands against, one
    per tick, so that the first Retarget of a session does not hold Blender while it makes all four
    (102 of its 113 ms); unregistering stops it."""
    out = run_blender(
        """
        import contact_edit_addon
        from contact_edit_addon import registration
        from solver.retarget import annotate
        timer = registration.make_procedural_topologies
        contact_edit_addon.register()
        registered = bpy.app.timers.is_registered(timer)
        ticks = [timer()]
        while ticks[-1] is not None:
            ticks.append(timer())
        made = sorted(annotate._TOPOLOGIES)
        contact_edit_addon.unregister()
        result(dict(registered=registered, ticks=ticks, made=made, after=bpy.app.timers.is_registered(timer)))
        """,
        tmp_path,
    )
    assert out["registered"] and not out["after"]
    assert out["ticks"] == [0.05] * (len(KINDS) - 1) + [None]
    assert out["made"] == sorted(KINDS)


def test_propose_annotation_refuses_what_it_cannot_read_naming_it(tmp_path):
    """Proposing an annotation needs a hand skinned to an armature with finger chains: a plain mesh, a
    wrist bone that is not there, and exporting before both hands have one are refused, saying why, and
    nothing is changed."""
    out = run_blender(
        """
        from contact_edit_addon import assets
        from solver import hands
        arm_hand, _ = assets.hand_objects(hands.make_hand("human"), "Human", scene.collection)
        messages = []
        for call in (lambda: bpy.ops.contact_edit.annotation_propose(object_name="Ball"),
                     lambda: bpy.ops.contact_edit.annotation_propose(object_name="Human", wrist="nope"),
                     lambda: bpy.ops.contact_edit.annotation_export(filepath="x.json")):
            try:
                call()
            except RuntimeError as err:
                messages.append(str(err))
        result(dict(messages=messages, annotation=arm_hand.contact_edit.annotation,
                    layer=arm_hand.contact_edit.layer))
        """,
        tmp_path,
        setup=SETUP,
    )
    ball, wrist, export = out["messages"]
    assert "'Ball' has no Armature modifier" in ball
    assert "the armature has no bone 'nope' to take as the wrist" in wrist
    assert "Choose the source hand in Retarget first" in export
    assert out["annotation"] == "" and out["layer"] == "CONTACTS"


def test_operators_explain_why_they_are_unavailable(tmp_path):
    out = run_blender(
        """
        import contact_edit_addon
        contact_edit_addon.register()
        bpy.ops.wm.read_factory_settings(use_empty=True)
        bpy.ops.object.empty_add()
        messages = {}
        for name in ("paint", "rotate", "transfer"):
            try:
                getattr(bpy.ops.contact_edit, name)()
            except RuntimeError as err:
                messages[name] = str(err)
        result(messages)
        """,
        tmp_path,
    )
    assert "Select a mesh object" in out["paint"]
    assert "Select a mesh object" in out["rotate"]
    assert "Choose the hand and the object" in out["transfer"]


def test_a_non_manifold_mesh_is_reported_with_its_faults_selected(tmp_path):
    out = run_blender(
        """
        import bmesh
        import contact_edit_addon
        contact_edit_addon.register()
        bpy.ops.wm.read_factory_settings(use_empty=True)
        bpy.ops.mesh.primitive_grid_add(x_subdivisions=4, y_subdivisions=4, size=2.0)
        obj = bpy.context.active_object
        bm = bmesh.new(); bm.from_mesh(obj.data)
        bm.edges.ensure_lookup_table()
        edge = next(e for e in bm.edges if len(e.link_faces) == 2)  # an inner edge: faces 3 and 4 on it
        extra = bm.verts.new((0.0, 0.0, 1.0))
        bm.faces.new((edge.verts[0], edge.verts[1], extra))
        bm.to_mesh(obj.data); bm.free()
        obj.data.vertices.foreach_set("select", [False] * len(obj.data.vertices))
        before = obj.contact_edit.data
        try:
            bpy.ops.contact_edit.paint(name="x", source="SELECTION")
            message = ""
        except RuntimeError as err:
            message = str(err)
        selected = [p.index for p in obj.data.polygons if p.select]
        result(dict(message=message, selected=selected, unchanged=obj.contact_edit.data == before))
        """,
        tmp_path,
    )
    assert "non-manifold" in out["message"] and "offending elements are selected" in out["message"]
    assert len(out["selected"]) >= 3
    assert out["unchanged"]


def test_a_proxy_carries_contacts_for_a_mesh_in_pieces(tmp_path):
    """Two overlapping spheres (one mesh, two pieces): the proxy is one manifold surface on top of them."""
    out = run_blender(
        """
        import numpy as np
        import contact_edit_addon
        contact_edit_addon.register()
        bpy.ops.wm.read_factory_settings(use_empty=True)
        bpy.ops.mesh.primitive_uv_sphere_add(radius=1.0, location=(0, 0, 0))
        bpy.ops.mesh.primitive_uv_sphere_add(radius=1.0, location=(1.2, 0, 0))
        bpy.ops.object.select_all(action="SELECT")
        bpy.ops.object.join()
        scan = bpy.context.active_object
        scan.name = "Scan"
        bpy.context.scene.contact_edit.target = scan
        bpy.ops.contact_edit.make_proxy()
        proxy = bpy.context.active_object
        from contact_edit_addon import bridge
        mesh = bridge.trimesh(proxy)
        X = bridge.object_to_world(proxy, mesh.vertices)
        to_surface = np.minimum(np.abs(np.linalg.norm(X, axis=1) - 1),
                                np.abs(np.linalg.norm(X - [1.2, 0, 0], axis=1) - 1))
        outside = (np.linalg.norm(X, axis=1) > 0.99) & (np.linalg.norm(X - [1.2, 0, 0], axis=1) > 0.99)
        target = bpy.context.scene.contact_edit.target.name
        result(dict(name=proxy.name, components=int(mesh.n_components), target=target,
                    gap=float(np.median(to_surface)), outside=float(outside.mean())))
        """,
        tmp_path,
    )
    assert out["name"] == "Scan (contact proxy)" and out["target"] == out["name"]
    assert out["components"] == 1  # one closed surface around the union
    assert out["gap"] < 0.02  # on the original surface (up to the UV spheres' faceting)
    assert out["outside"] > 0.95  # the outer shell, not the buried halves


def test_panel_messages_wrap_to_the_sidebar_width_instead_of_being_cut(tmp_path):
    out = run_blender(
        """
        import blf
        from types import SimpleNamespace
        from contact_edit_addon.ui import panels
        text = "1877 contacts in 2 patch pairs mean distance 2.52 cm, largest 9.87 cm, stopped by you"
        found = {}
        for width, scale in ((291, 1.0), (200, 1.0), (400, 2.0)):
            context = SimpleNamespace(preferences=SimpleNamespace(system=SimpleNamespace(ui_scale=scale)),
                                      region=SimpleNamespace(width=width))
            lines = panels.wrapped(context, text)
            blf.size(0, 11 * scale)
            found[f"{width}@{scale}"] = dict(lines=lines, widths=[blf.dimensions(0, l)[0] for l in lines],
                                             room=width - panels.LABEL_MARGIN * scale)
        result(found)
        """,
        tmp_path,
        setup="import contact_edit_addon\n",
    )
    text = "1877 contacts in 2 patch pairs mean distance 2.52 cm, largest 9.87 cm, stopped by you"
    for case in out.values():
        assert " ".join(case["lines"]) == text
        assert max(case["widths"]) <= case["room"] and len(case["lines"]) >= 2
    assert len(out["200@1.0"]["lines"]) > len(out["291@1.0"]["lines"])


def test_the_example_lands_clear_of_the_startup_cube(tmp_path):
    """Issue 37: *Add › Contact Edit › Example* in Blender's startup scene put the hand and mug inside the
    default 2 m cube (the view showed grey walls). They land beside it, the mug still at the hand."""
    out = run_blender(
        """
        import numpy as np
        import contact_edit_addon
        contact_edit_addon.register()
        bpy.ops.wm.read_factory_settings()
        from mathutils import Vector
        def box(obj):
            corners = np.array([tuple(obj.matrix_world @ Vector(c)) for c in obj.bound_box])
            return corners.min(0).tolist(), corners.max(0).tolist()
        bpy.ops.contact_edit.add_example()
        scene = bpy.context.scene
        hand, mug = scene.contact_edit.hand, scene.contact_edit.target
        result(dict(cube=box(bpy.data.objects["Cube"]), hand=box(hand), mug=box(mug),
                    active=bpy.context.view_layer.objects.active.name))
        """,
        tmp_path,
    )
    cube = np.array(out["cube"])
    for name in ("hand", "mug"):
        lo, hi = np.array(out[name])
        assert not np.all((lo < cube[1]) & (cube[0] < hi)), name
    (h_lo, h_hi), (m_lo, m_hi) = np.array(out["hand"]), np.array(out["mug"])
    assert np.linalg.norm((h_lo + h_hi) / 2 - (m_lo + m_hi) / 2) < 0.2 and out["active"] == "Hand"
