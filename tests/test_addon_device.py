"""Driving an armature live from the puppet device in the real bpy 5.0.1 module: a simulated device on a
pseudo-terminal, read by the SerialReader, binds to the procedural hand's bones, shape keys and
properties; the poses Blender ends up with are checked against what the simulator sent.

Nothing here depends on how much wall time passes (the machine may be busy): the scripts update when the
reader has published what they wait for (new readings, a joint detached), each wait bounded only by the
generous ``WAIT``, and the blink runs on a clock the script moves on by hand."""

import importlib.util

import numpy as np
import pytest

from tangible import Command
from tangible.protocol import MIN_ID

from .blender import run_blender

J = MIN_ID  # the simulated pieces carry firmware ids: J + 11, ...

pytestmark = pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="needs bpy (the dev extra)")


SETUP = """
import ctypes, os, tempfile, threading, time
import numpy as np
import contact_edit_addon
contact_edit_addon.register()
from contact_edit_addon import assets
from contact_edit_addon.device import session as device_session
from contact_edit_addon.device import bridge as device_bridge
from contact_edit_addon.device import operators as device
from solver import hands
from tangible import (SPLITTERS, DeviceTree, Faults, Piece, PoseSpace, RandomMotion, Simulator, joint_angles,
                      joint_rotation)
from tangible import rotations as rot
from tangible.protocol import MIN_ID as J, DataRecord
# Longest wait for a state of the reader. A wait ends as soon as its state holds, so this only bounds how
# long a broken build hangs. Connecting and zeroing wait as long: on a busy machine the device may take
# more than the session's usual timeouts to show its joints or acknowledge a command (both waits end as
# soon as it has). Scripts that expect a connection to fail put the usual timeout back.
WAIT = 60.0
CONNECT_TIMEOUT = device_session.CONNECT_TIMEOUT
device_session.CONNECT_TIMEOUT = device_session.ACK_TIMEOUT = WAIT
bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
hand, armature = assets.hand_objects(hands.make_hand("human"), "Hand", scene.collection)
for pose_bone in armature.pose.bones:  # the hand's anatomical limits would clamp the evaluated pose
    for constraint in list(pose_bone.constraints):
        pose_bone.constraints.remove(constraint)
settings = scene.contact_edit_device
settings.armature = armature
NAMES = [b.name for b in armature.data.bones]  # parents first, as the session orders them

# Joint 11 on the host, a T splitter 12 with the chain 13-15 in one slot and 14 in the other (ids J + n).
DEVICE = DeviceTree([Piece(J + 11, "joint"), Piece(J + 12, "splitter", J + 11, splitter=SPLITTERS["T"]),
                     Piece(J + 13, "joint", J + 12, 0), Piece(J + 15, "joint", J + 13),
                     Piece(J + 14, "joint", J + 12, 1)])
BONES = {J + 11: "hand", J + 13: "index_1", J + 15: "index_2", J + 14: "thumb_1"}
for name, mode in {"hand": "QUATERNION", "index_2": "ZXY", "thumb_1": "AXIS_ANGLE"}.items():
    armature.pose.bones[name].rotation_mode = mode  # index_1 stays XYZ

def bind_bones(joints=BONES):
    for joint, bone in joints.items():
        bpy.ops.contact_edit.device_bind(joint=joint, target="BONE", bone=bone)

def basis(name):
    '''The bone's local rotation as Blender reads its channels (whatever the rotation mode).'''
    return np.array(armature.pose.bones[name].matrix_basis.to_quaternion())

def degrees(a, b):
    return float(np.degrees(rot.angle(np.asarray(a, float), np.asarray(b, float))))

def set_rotation(name, q):
    device_bridge.write_rotations(armature, [name], np.asarray(q, float)[None])

def channels():
    return {b.name: (b.rotation_mode, tuple(b.rotation_quaternion), tuple(b.rotation_euler),
                     tuple(b.rotation_axis_angle)) for b in armature.pose.bones}

def reported(call):
    '''Run call (an operator); return its result, or the error it raised, and what it reported.'''
    libc = ctypes.CDLL(None)
    with tempfile.TemporaryFile(mode="w+") as out:
        sys.stdout.flush(); sys.stderr.flush(); libc.fflush(None)
        saved = os.dup(1), os.dup(2)
        os.dup2(out.fileno(), 1); os.dup2(out.fileno(), 2)
        try:
            value = call()
        except RuntimeError as err:
            value = str(err)
        finally:
            sys.stdout.flush(); sys.stderr.flush(); libc.fflush(None)
            os.dup2(saved[0], 1); os.dup2(saved[1], 2)
            os.close(saved[0]); os.close(saved[1])
        out.seek(0)
        return value, out.read()

def sample_poses(n, seed):
    '''Key n random poses of every bone in an action of its own (not left assigned), return them (n, b, 4)
    as Blender reads them back.'''
    rng = np.random.default_rng(seed)
    samples = np.empty((n, len(NAMES), 4))
    for k in range(n):
        for b, name in enumerate(NAMES):
            v = rng.normal(size=3); v *= rng.uniform(0.1, 0.8) / np.linalg.norm(v)
            set_rotation(name, rot.from_rotvec(v) if b else rot.IDENTITY)
            pose_bone = armature.pose.bones[name]
            pose_bone.keyframe_insert(device_bridge.rotation_path(pose_bone.rotation_mode), frame=k + 1)
            samples[k, b] = basis(name)
    action = armature.animation_data.action
    action.name = "Samples"
    armature.animation_data.action = None
    for name in NAMES:
        set_rotation(name, rot.IDENTITY)
    return action, samples

def truth(simulator):
    '''Joint rotations the simulator sent intact, by (joint, raw angles of the record).'''
    return {(s.record.creator, s.record.raw): s.rotation
            for s in simulator.history if s.intact and isinstance(s.record, DataRecord)}

def session():
    return device_session.sessions[armature.name]

def until(predicate, what, timeout=WAIT):
    '''The session's reader's first state for which predicate holds; fails saying what it waited for.'''
    reader = session().reader
    state = reader.wait_for(predicate, timeout)
    if state is None:
        raise AssertionError(f"waited {timeout:g} s for {what}; the reader is at {reader.state()}")
    return state

def newer(joints, than):
    '''A predicate: a state has readings of every one of joints newer than the state than has.'''
    def data_time(state, j):
        c = state.components.get(j)
        return -np.inf if c is None or c.data_time is None else c.data_time
    before = {j: data_time(than, j) for j in joints}
    return lambda s: all(data_time(s, j) > before[j] for j in joints)

def update_on_new_readings(joints):
    '''Once the reader has new readings of every one of joints (newer than those the armature shows),
    apply the device's state.'''
    until(newer(joints, session().state), f"new readings of joints {sorted(joints)}")
    bpy.ops.contact_edit.device_update()

def update_until_turned(joints, names, by):
    '''Apply the device's state on each new reading of joints until each of their bones has turned by more
    than by degrees from where it is now (a few readings: the motions are smooth and quick); return how
    far each bone in names turned, in degrees.'''
    first = {n: basis(n) for n in names}
    give_up = time.monotonic() + WAIT  # only when something is broken
    while True:
        update_on_new_readings(joints)
        turned = {n: degrees(first[n], basis(n)) for n in names}
        if all(turned[BONES[j]] > by for j in joints) or time.monotonic() > give_up:
            return turned

class FakeLayout:
    '''Stands in for a UILayout (there is no window in background mode): checks that every property,
    operator, menu and list the panel names exists, and records what it shows.'''
    def __init__(self, shown):
        self.shown, self.enabled, self.operator_context = shown, True, "INVOKE_DEFAULT"
    def row(self, **_):
        return FakeLayout(self.shown)
    column = box = row
    def prop(self, data, name, **_):
        assert name in data.bl_rna.properties, name
        self.shown.append(name)
    def prop_search(self, data, name, search_data, search_name, **_):
        assert name in data.bl_rna.properties and search_name in search_data.bl_rna.properties, name
        self.shown.append(name)
    def label(self, text="", **_):
        self.shown.append(text)
    def operator(self, idname, **_):
        category, name = idname.split(".")
        getattr(getattr(bpy.ops, category), name).get_rna_type()
        self.shown.append(idname)
        return type("Properties", (), {})()
    def menu(self, name, **_):
        assert hasattr(bpy.types, name), name
    def template_list(self, list_type, _id, data, name, active_data, active_name, **_):
        assert hasattr(bpy.types, list_type) and name in data.bl_rna.properties
        assert active_name in active_data.bl_rna.properties
        for i, item in enumerate(getattr(data, name)):
            bpy.types.CONTACT_EDIT_UL_device_bindings.draw_item(None, bpy.context, self, data, item, 0, data,
                                                                 active_name, i)

def panel_shows():
    from contact_edit_addon.device import panel as device_panel
    shown = []
    panel = device_panel.VIEW3D_PT_contact_edit_device
    fake = type("Panel", (), {"layout": FakeLayout(shown), **{name: staticmethod(getattr(panel, name))
            for name in dir(panel) if name.startswith("draw_")}})()
    panel.draw(fake, bpy.context)
    device_panel.CONTACT_EDIT_MT_device_ports.draw(type("Menu", (), {"layout": FakeLayout(shown)})(),
                                                  bpy.context)
    return shown
"""


def test_driven_bones_equal_simulated_joints_through_corrupted_frames(tmp_path):
    """Simulator → pty → SerialReader → armature with 5% of frames damaged: every driven bone, read back
    from Blender in its own rotation mode, equals the joint rotation the simulator sent in the frame the
    reader accepted; the other bones follow the sample poses by pose interpolation."""
    out = run_blender(
        """
        action, samples = sample_poses(6, seed=3)
        settings.sample_action = action
        bind_bones()
        motion, faults = RandomMotion(4, seed=11), Faults.corrupt(0.05)
        simulator = Simulator(DEVICE, motion=motion, faults=faults, seed=5).start()
        settings.port = simulator.path
        bpy.ops.contact_edit.device_connect()
        bound = [NAMES.index(BONES[j]) for j in BONES]
        followers = [b for b in range(1, len(NAMES)) if b not in bound]
        oracle = PoseSpace(samples[:, bound], samples[:, followers])
        seen, interpolation_error, ticks = [], 0.0, []
        def damage_seen():
            link = session().state.link
            return simulator.stats.corrupted > 10 and link.corrupt + link.oversize > 0
        # An update on every new set of readings, 70 of them and then on until some frames were damaged
        # (5%: a dozen comes within a few dozen more).
        while len(ticks) < 70 or (not damage_seen() and len(ticks) < 5000):
            until(newer(BONES, session().state), "new readings")
            started = time.perf_counter()
            bpy.ops.contact_edit.device_update()
            ticks.append(time.perf_counter() - started)
            state = session().state
            seen += [(j, state.components[j].raw, basis(BONES[j])) for j in BONES]
            keys = np.array([basis(NAMES[b]) for b in bound])
            expected = oracle(keys)
            interpolation_error = max(interpolation_error, max(
                degrees(basis(NAMES[b]), q) for b, q in zip(followers, expected)))
        status = settings.status
        simulator.stop()
        sent = truth(simulator)
        errors = [degrees(q, sent[j, seq]) for j, seq, q in seen if (j, seq) in sent]
        unsent = len({(j, seq) for j, seq, _ in seen if (j, seq) not in sent})
        link = session().state.link
        bpy.ops.contact_edit.device_stop()
        simulator.close()
        result(dict(max_error=max(errors), compared=len(errors), distinct=len({(j, s) for j, s, _ in seen}),
                    unsent=unsent,
                    interpolation_error=interpolation_error, corrupted=simulator.stats.corrupted,
                    intact=simulator.stats.intact, damaged=link.corrupt + link.oversize, status=status,
                    followers=len(followers), tick_ms=1000 * float(np.median(ticks))))
        """,
        tmp_path,
        setup=SETUP,
    )
    print(
        f"\nmax bone error {out['max_error']:.4f}° over {out['compared']} readings "
        f"({out['distinct']} distinct frames); {out['corrupted']} of "
        f"{out['corrupted'] + out['intact']} frames corrupted, {out['damaged']} rejected by the reader; "
        f"interpolated bones within "
        f"{out['interpolation_error']:.4f}° of the pose space; median update {out['tick_ms']:.2f} ms"
    )
    assert out["max_error"] < 0.5  # the device's accuracy; quantization alone is 0.003°
    # Readings no intact record carried: damaged records that passed CRC-8 by chance (1 in 256 of them).
    assert out["unsent"] <= 2
    assert out["distinct"] > 100
    assert out["corrupted"] > 10 and out["damaged"] > 0
    assert out["interpolation_error"] < 0.05
    assert out["followers"] == 12
    assert out["status"].startswith("Live on") and "12 following by interpolation" in out["status"]


def test_silence_freezes_the_pose_and_says_so_and_stop_restores_it(tmp_path):
    out = run_blender(
        """
        rng = np.random.default_rng(2)
        for name in NAMES[1:]:
            set_rotation(name, rot.from_rotvec(rng.normal(scale=0.3, size=3)))
        before = channels()
        bind_bones()
        link = os.path.join(tempfile.mkdtemp(), "puppet")  # a stable name, like /dev/serial/by-id
        motion = RandomMotion(4, seed=1, speed=2.0)
        simulator = Simulator(DEVICE, motion=motion, seed=3, link=link).start()
        settings.port = link
        bpy.ops.contact_edit.device_connect()
        reader = session().reader
        bound, subtree = list(BONES), ["index_1", "index_2", "thumb_1"]  # the splitter's bones
        def bone_drift(first):
            return max(degrees(first[n], basis(n)) for n in first)
        bpy.ops.contact_edit.device_update()
        moving_at_start = min(update_until_turned(bound, BONES.values(), 1.0).values())

        # The live operator's timer step, run by hand (background mode has no window for the timer).
        Live = device.CONTACT_EDIT_OT_device_connect
        class LiveOperator:
            _end = Live._end
            def __init__(self):
                self._armature, self._session, self._reported, self._timer = armature.name, session(), "", 1
                self.reports = []
            def report(self, level, message):
                self.reports.append((next(iter(level)), message))
        live, removed = LiveOperator(), []
        manager = type("WindowManager", (), {"event_timer_remove": removed.append})
        window = type("Context", (), {"scene": scene, "screen": None, "window_manager": manager})
        def timer_step():
            return Live.modal(live, window, type("Event", (), {"type": "TIMER"}))

        # The splitter's subtree loses power: after the 2 s rule its bones hold, the rest moves on (the drift
        # is measured over updates that provably applied new readings: the hand turned meanwhile).
        simulator.set_power(J + 12, False)
        cut = [J + 12, J + 13, J + 14, J + 15]
        def subtree_detached(s):
            return s.components[J + 11].attached and not any(s.components[j].attached for j in cut)
        detached = until(subtree_detached, "the splitter's subtree detached") is not None
        _, subtree_report = reported(bpy.ops.contact_edit.device_update)
        live_steps = [timer_step(), timer_step()]
        silent_since = session().state
        turned = update_until_turned([J + 11], ["hand", *subtree], 0.1)
        subtree_drift, live_motion = max(turned[n] for n in subtree), turned["hand"]
        simulator.set_power(J + 12, True)
        back = newer(cut[1:], silent_since)
        until(lambda s: all(s.components[j].attached for j in cut) and back(s), "the subtree back, reading")
        _, back_report = reported(bpy.ops.contact_edit.device_update)
        live_steps.append(timer_step())
        moving_again = min(update_until_turned(cut[1:], subtree, 0.1).values())

        # The cable is pulled: the port fails at once; plugged back in, the reader reopens it. While it is
        # out the pose holds, however far the device (its motion, on its own clock) turns meanwhile.
        simulator.unplug()
        until(lambda s: not s.connected, "the port to fail")
        _, unplugged_report = reported(bpy.ops.contact_edit.device_update)
        unplugged_at, first = simulator.time, {n: basis(n) for n in BONES.values()}
        give_up = time.monotonic() + WAIT
        while (rot.angle(motion(simulator.time), motion(unplugged_at)).min() < np.radians(1.0)
               and time.monotonic() < give_up):
            bpy.ops.contact_edit.device_update()
            time.sleep(0.01)
        bpy.ops.contact_edit.device_update()
        unplugged_drift = bone_drift(first)
        device_turned = float(np.degrees(rot.angle(motion(simulator.time), motion(unplugged_at)).min()))
        lost = session().state
        simulator.replug()
        back = newer(bound, lost)
        until(lambda s: s.connected and all(s.components[j].attached for j in bound) and back(s),
              "the device back, reading")
        bpy.ops.contact_edit.device_update()
        replugged_motion = min(update_until_turned(bound, BONES.values(), 0.1).values())

        # The device stops altogether: the 2 s rule detaches every joint; the pose holds while the reader
        # polls on and hears nothing.
        simulator.stop()
        until(lambda s: not any(s.components[j].attached for j in bound), "every joint detached")
        _, silent_report = reported(bpy.ops.contact_edit.device_update)
        first, missing = {n: basis(n) for n in BONES.values()}, session().state.link.missing
        until(lambda s: s.link.missing >= missing + 10, "ten polls more without a reply")
        bpy.ops.contact_edit.device_update()
        silent_drift = bone_drift(first)
        stop_result, stop_report = reported(bpy.ops.contact_edit.device_stop)
        after = channels()
        live_steps.append(timer_step())
        update_after_stop, _ = reported(bpy.ops.contact_edit.device_update)
        simulator.close()
        result(dict(moving_at_start=moving_at_start, detached=detached, subtree_report=subtree_report,
                    subtree_drift=subtree_drift, live_motion=live_motion, back_report=back_report,
                    moving_again=moving_again, unplugged_report=unplugged_report,
                    unplugged_drift=unplugged_drift, device_turned=device_turned,
                    replugged_motion=replugged_motion,
                    silent_report=silent_report, silent_drift=silent_drift,
                    stop_result=list(stop_result), stop_report=stop_report, restored=after == before,
                    touched=[n for n in before if before[n] != after[n]],
                    sessions=len(device_session.sessions),
                    update_after_stop=update_after_stop, status=settings.status,
                    live_steps=[sorted(step) for step in live_steps], live_reports=live.reports,
                    timer_removed=removed,
                    threads=[t.name for t in threading.enumerate() if t.name.startswith("tangible")]))
        """,
        tmp_path,
        setup=SETUP,
    )
    assert out["moving_at_start"] > 1.0
    assert out["detached"]
    report = out["subtree_report"]
    assert "Warning" in report and f"{J + 13}, {J + 14}, {J + 15}" in report and "frozen" in report
    assert "'index_1'" in report
    assert out["subtree_drift"] < 1e-6 and out["live_motion"] > 0.1
    assert "Live on" in out["back_report"] and out["moving_again"] > 0.1
    # The live timer reports the freeze once, and the recovery; once stopped it ends and removes its timer.
    assert out["live_steps"] == [["PASS_THROUGH"]] * 3 + [["CANCELLED"]] and out["timer_removed"] == [1]
    assert [level for level, _ in out["live_reports"]] == ["WARNING", "INFO"]
    assert "fell silent" in out["live_reports"][0][1]
    assert "Warning" in out["unplugged_report"] and "Lost the port" in out["unplugged_report"]
    assert out["device_turned"] > 1.0 and out["unplugged_drift"] < 1e-6 and out["replugged_motion"] > 0.1
    assert "Warning" in out["silent_report"] and "is silent: the pose is frozen" in out["silent_report"]
    assert out["silent_drift"] < 1e-6
    assert out["stop_result"] == ["FINISHED"] and "pose from before connecting is back" in out["stop_report"]
    assert out["restored"], out["touched"]
    assert out["sessions"] == 0 and out["threads"] == []
    assert "No device is driving 'Hand rig'" in out["update_after_stop"]
    assert out["status"].startswith("Stopped")


def test_calibration_shape_keys_properties_recording_and_sample_poses(tmp_path):
    out = run_blender(
        """
        from bpy_extras import anim_utils
        from mathutils import Euler
        action, samples = sample_poses(5, seed=8)
        rng = np.random.default_rng(4)
        for name in BONES.values():
            set_rotation(name, rot.from_rotvec(rng.normal(scale=0.4, size=3)))
        start = {n: basis(n) for n in BONES.values()}
        bpy.ops.mesh.primitive_plane_add()
        face = bpy.context.active_object
        face.name = "Face"
        face.shape_key_add(name="Basis"); face.shape_key_add(name="Smile").value = 0.2
        face["open"] = -1.0
        bpy.context.view_layer.objects.active = armature
        bind_bones({J + 11: "hand", J + 13: "index_1", J + 14: "thumb_1"})
        bpy.ops.contact_edit.device_bind(joint=J + 15, target="SHAPE_KEY", object_name="Face",
                                         shape_key="Smile", channel="bend_a", source_min=0.0,
                                         source_max=np.pi / 2)
        bpy.ops.contact_edit.device_bind(joint=J + 14, target="PROPERTY", object_name="Face",
                                         data_path='["open"]', channel="twist", source_min=0.0,
                                         source_max=np.pi, target_max=2.0)
        angles = np.zeros((4, 4))  # the joints' angles (record order), in DEVICE.joints order, set by hand
        simulator = Simulator(DEVICE, motion=lambda t: joint_rotation(angles), seed=6).start()
        settings.port = simulator.path
        bpy.ops.contact_edit.device_connect()
        reader = session().reader
        order = DEVICE.joints
        def hold(target):
            '''Hold the device at angles (4, 4) and update once the reader has them.'''
            angles[:] = target
            want = joint_rotation(target)
            until(lambda s: all(rot.angle(s.components[j].rotation, want[i]) < 2e-3
                                for i, j in enumerate(order)), "the device held at the angles")
            bpy.ops.contact_edit.device_update()
            return {j: joint_rotation(target[i]) for i, j in enumerate(order)}
        def random_angles():
            a = rng.uniform(-0.6, 0.6, (4, 4)); a[:, [0, 3]] = rng.uniform(-3, 3, (4, 2))
            return a
        def worst(expected):
            return max(degrees(basis(BONES[j]), q) for j, q in expected.items() if j != J + 15)

        settings.active_binding = 3  # the shape key
        shown_live = panel_shows()
        settings.active_binding = 0
        shown_live += panel_shows()

        # Calibrate to the rest pose with the device held at A: the bones are at rest, and after moving to
        # B each bone turns by the joint's turn from A to B.
        A = hold(random_angles())
        bpy.ops.contact_edit.device_calibrate(pose="REST")
        at_rest = worst({j: rot.IDENTITY for j in A})
        B = hold(random_angles())
        rest_turn = worst({j: rot.multiply(rot.conjugate(A[j]), B[j]) for j in A})
        # Calibrate to the pose from before connecting with the device at B, then move to C.
        bpy.ops.contact_edit.device_calibrate(pose="START")
        at_start = worst({j: start[BONES[j]] for j in A})
        C = hold(random_angles())
        start_turn = worst({j: rot.multiply(start[BONES[j]], rot.multiply(rot.conjugate(B[j]), C[j]))
                            for j in A})

        # Shape key and property: bend_a 0..90° -> Smile 0..1, clamped; twist 0..180° -> open 0..2.
        smile = face.data.shape_keys.key_blocks["Smile"]
        numbers = []
        for bend_a, twist in ((np.pi / 4, np.pi / 2), (np.pi / 8, np.pi / 4), (-0.3, 0.2)):
            target = np.zeros((4, 4)); target[2, 1] = bend_a; target[3, [0, 3]] = twist / 2
            hold(target)
            numbers.append((smile.value, face["open"]))

        # Record every frame, then on demand.
        settings.record = "EVERY_FRAME"
        recorded = {}
        for frame in (1, 2, 3, 4):
            scene.frame_set(frame)
            hold(random_angles())
            recorded[frame] = (basis("hand"), basis("index_1"), smile.value)
        def curves(idblock):
            data = idblock.animation_data
            bag = anim_utils.action_get_channelbag_for_slot(data.action, data.action_slot)
            return {(c.data_path, c.array_index): c for c in bag.fcurves}
        settings.record = "ON_DEMAND"
        scene.frame_set(10); hold(random_angles())
        keyed_before_asking = any(k.co[0] == 10 for c in curves(armature).values() for k in c.keyframe_points)
        bpy.ops.contact_edit.device_key()
        settings.record = "OFF"
        scene.frame_set(20); hold(random_angles())
        bones = curves(armature)
        def key_frames(path):
            return sorted({k.co[0] for (p, _), c in bones.items() if p == path for k in c.keyframe_points})
        hand_path = 'pose.bones["hand"].rotation_quaternion'
        index_path = 'pose.bones["index_1"].rotation_euler'
        replay = 0.0
        for frame, (hand_q, index_q, smile_value) in recorded.items():
            q = [bones[hand_path, i].evaluate(frame) for i in range(4)]
            e = [bones[index_path, i].evaluate(frame) for i in range(3)]
            replay = max(replay, degrees(q / np.linalg.norm(q), hand_q),
                         degrees(np.array(Euler(e, "XYZ").to_quaternion()), index_q))
        shape_curves = curves(face.data.shape_keys).values()
        shape_frames = sorted(k.co[0] for c in shape_curves for k in c.keyframe_points)
        property_frames = sorted(k.co[0] for c in curves(face).values() for k in c.keyframe_points)

        # Sample poses: with the bound bones exactly at a sample's rotations, every other bone is there too.
        for b in settings.bindings:
            b.rest, b.pose = (1, 0, 0, 0), (1, 0, 0, 0)
        settings.sample_action = action
        bound = [NAMES.index(n) for n in ("hand", "index_1", "thumb_1")]
        reproduced = 0.0
        for k in (0, 3):
            target = np.zeros((4, 4))
            target[[0, 1, 3]] = joint_angles(samples[k, bound])
            hold(target)
            reproduced = max(reproduced, max(degrees(basis(NAMES[b]), samples[k, b])
                                             for b in range(1, len(NAMES))))
        bpy.ops.contact_edit.device_stop()
        simulator.close()
        result(dict(at_rest=at_rest, rest_turn=rest_turn, at_start=at_start, start_turn=start_turn,
                    numbers=numbers, hand_frames=key_frames(hand_path), index_frames=key_frames(index_path),
                    keyed_before_asking=keyed_before_asking, replay=replay, shape_frames=shape_frames,
                    property_frames=property_frames, reproduced=reproduced,
                    smile_after_stop=smile.value, open_after_stop=face["open"], shown_live=shown_live,
                    shown_stopped=panel_shows()))
        """,
        tmp_path,
        setup=SETUP,
    )
    calibration = ("at_rest", "rest_turn", "at_start", "start_turn")
    print(
        "\ncalibration errors "
        + ", ".join(f"{name} {out[name]:.4f}°" for name in calibration)
        + f"; keys replay within {out['replay']:.5f}°"
        + f"; sample poses reproduced within {out['reproduced']:.4f}°"
    )
    for name in calibration:
        assert out[name] < 0.5, name
    assert out["numbers"] == [
        pytest.approx([0.5, 1.0], abs=1e-3),
        pytest.approx([0.25, 0.5], abs=1e-3),
        pytest.approx([0.0, 0.4 / 3.14159265], abs=1e-3),  # a negative bend clamps to the range's end
    ]
    assert out["hand_frames"] == out["index_frames"] == [1, 2, 3, 4, 10]
    assert not out["keyed_before_asking"]
    assert out["shape_frames"] == [1, 2, 3, 4, 10] and out["property_frames"] == [1, 2, 3, 4, 10]
    assert out["replay"] < 0.01
    assert out["reproduced"] < 0.5
    # The panel: live joints to bind, calibration, the scalar binding's settings; Connect once stopped.
    live = out["shown_live"]
    assert (
        any(text.startswith(f"Joint {J + 11} (") for text in live)  # its id and colour
        and "contact_edit.device_calibrate" in live
        and "contact_edit.device_stop" in live
    )
    assert "shape_key" in live and "channel" in live and "bone" in live and "Face: Smile" in live
    assert "contact_edit.device_connect" in out["shown_stopped"]
    assert out["smile_after_stop"] == pytest.approx(0.2) and out["open_after_stop"] == -1.0  # as before


def test_bad_input_is_refused_clearly_and_changes_nothing(tmp_path):
    out = run_blender(
        """
        rng = np.random.default_rng(5)
        for name in NAMES[1:]:
            set_rotation(name, rot.from_rotvec(rng.normal(scale=0.3, size=3)))
        device_session.CONNECT_TIMEOUT = CONNECT_TIMEOUT  # the connections here fail: after the usual wait
        threads = threading.active_count()
        errors = {}
        def attempt(key, call):
            errors[key] = reported(call)[0]

        settings.armature = None
        bpy.context.view_layer.objects.active = hand
        attempt("no armature", bpy.ops.contact_edit.device_connect)
        attempt("bind without armature", lambda: bpy.ops.contact_edit.device_bind(joint=1, bone="hand"))
        settings.armature = armature
        attempt("unknown bone", lambda: bpy.ops.contact_edit.device_bind(joint=1, bone="tail"))
        attempt("no shape key", lambda: bpy.ops.contact_edit.device_bind(
            joint=2, target="SHAPE_KEY", object_name="Hand", shape_key="Smile"))
        attempt("not a number", lambda: bpy.ops.contact_edit.device_bind(
            joint=2, target="PROPERTY", object_name="Hand", data_path="name"))
        bind_bones()
        before, bindings = channels(), [(b.joint, b.bone) for b in settings.bindings]
        attempt("no port", bpy.ops.contact_edit.device_connect)
        settings.port = "/dev/ttyNOSUCHPORT"
        attempt("unknown port", bpy.ops.contact_edit.device_connect)
        settings.port = "carrier-pigeon://coop"
        attempt("bad url", bpy.ops.contact_edit.device_connect)

        master, slave = os.openpty()
        stop = threading.Event()
        def spew():
            noise = np.random.default_rng(1)
            while not stop.is_set():
                os.write(master, noise.integers(0, 256, 256, dtype=np.uint8).tobytes())
                stop.wait(0.005)
        spewer = threading.Thread(target=spew); spewer.start()
        settings.port = os.ttyname(slave)
        started = time.perf_counter()
        attempt("garbage", bpy.ops.contact_edit.device_connect)
        garbage_seconds = time.perf_counter() - started
        stop.set(); spewer.join(); os.close(master); os.close(slave)

        simulator = Simulator(DEVICE, motion=RandomMotion(4, seed=2), seed=1).start()
        settings.port = simulator.path
        extra = settings.bindings.add(); extra.joint, extra.bone = 99, "pinky_1"
        wait_for_device = device.wait_for_device
        def whole_device_first(reader, *args):
            '''The refusal names the joints attached when it gives up: let the device show them all first.'''
            reader.wait_for(lambda s: all((c := s.components.get(j)) is not None and c.attached and
                                          c.angles is not None for j in DEVICE.joints), WAIT)
            return wait_for_device(reader, *args)
        device.wait_for_device = whole_device_first
        attempt("missing joint", bpy.ops.contact_edit.device_connect)
        device.wait_for_device = wait_for_device
        extra.bone = "index_1"
        attempt("bone bound twice", bpy.ops.contact_edit.device_connect)
        settings.bindings.remove(len(settings.bindings) - 1)
        simulator.close()
        attempt("update without device", bpy.ops.contact_edit.device_update)
        attempt("calibrate without device", bpy.ops.contact_edit.device_calibrate)
        attempt("stop without device", bpy.ops.contact_edit.device_stop)
        attempt("propose without samples", bpy.ops.contact_edit.device_propose)
        result(dict(errors=errors, unchanged=channels() == before, status=settings.status,
                    bindings=[(b.joint, b.bone) for b in settings.bindings] == bindings,
                    sessions=len(device_session.sessions), threads=threading.active_count() - threads,
                    garbage_seconds=garbage_seconds))
        """,
        tmp_path,
        setup=SETUP,
    )
    e = out["errors"]
    assert (
        "Choose the armature to drive" in e["no armature"]
        and "Choose the armature" in e["bind without armature"]
    )
    assert "'Hand rig' has no bone called 'tail'" in e["unknown bone"]
    assert "'Hand' has no shape key called 'Smile'" in e["no shape key"]
    assert "is not a number" in e["not a number"]
    assert "Choose the device's port first" in e["no port"]
    assert (
        "Cannot open the port '/dev/ttyNOSUCHPORT'" in e["unknown port"] and "simulator" in e["unknown port"]
    )
    assert "carrier-pigeon://coop" in e["bad url"]
    assert "sends data, but no puppet device messages" in e["garbage"] and "right port" in e["garbage"]
    assert "Joint 99 of the bindings is not attached" in e["missing joint"]
    assert f"attached joints: {J + 11}, {J + 13}, {J + 15}, {J + 14}" in e["missing joint"]
    assert f"'index_1' is bound to joints {J + 13} and 99" in e["bone bound twice"]
    for key in ("update without device", "calibrate without device", "stop without device"):
        assert "No device is driving 'Hand rig': connect one first" in e[key], key
    assert "Choose the sample poses" in e["propose without samples"]
    assert out["unchanged"] and out["bindings"] and out["status"] == ""
    assert out["sessions"] == 0 and out["threads"] == 0
    # It gave up after the connect timeout (1.5 s; how long that took on the clock depends on the machine).
    assert "damaged spots in 1.5 s" in e["garbage"]
    print(f"\nrefused a port sending garbage after {out['garbage_seconds']:.2f} s")


def test_proposed_device_binds_and_drives_through_the_builtin_simulator(tmp_path):
    out = run_blender(
        """
        action, samples = sample_poses(8, seed=12)
        settings.sample_action = action
        settings.kit_joints, settings.kit_t = 4, 1
        proposed, report = reported(bpy.ops.contact_edit.device_propose)
        planned = {b.joint: (b.bone, tuple(b.rest)) for b in settings.bindings}
        plan = settings.plan
        instructions = bpy.data.texts["Device assembly"].as_string()
        settings.simulator, settings.simulator_corruption, settings.simulator_seed = True, 5.0, 9
        bpy.ops.contact_edit.device_connect()
        live = {b.joint: b.bone for b in settings.bindings}
        simulator = session().simulator
        seen = []
        # An update on every new set of readings, 40 of them and then on until some frame was damaged.
        while len(seen) < 40 * len(live) or (simulator.stats.corrupted == 0 and len(seen) < 5000):
            update_on_new_readings(live)
            state = session().state
            seen += [(j, state.components[j].raw, basis(bone)) for j, bone in live.items()]
        followers = len(session().written_bones) - len(live)
        simulator.stop()
        sent = truth(simulator)
        rest = {J + j: np.array(r) for j, (_, r) in planned.items()}  # the simulated pieces' ids
        errors = [degrees(q, rot.multiply(rot.conjugate(rest[j]), sent[j, seq])) for j, seq, q in seen
                  if (j, seq) in sent]
        unsent = len({(j, seq) for j, seq, _ in seen if (j, seq) not in sent})  # CRC-8's chance, as above
        bpy.ops.contact_edit.device_stop()
        result(dict(proposed=list(proposed), report=report, planned={j: b for j, (b, _) in planned.items()},
                    live=live, plan_left=settings.plan, had_plan=bool(plan), instructions=instructions,
                    max_error=max(errors), compared=len(errors), corrupted=simulator.stats.corrupted,
                    followers=followers, unsent=unsent,
                    threads=[t.name for t in threading.enumerate() if t.name.startswith("tangible")]))
        """,
        tmp_path,
        setup=SETUP,
    )
    assert out["proposed"] == ["FINISHED"] and "Proposed 4 joints and" in out["report"]
    assert len(out["planned"]) == 4 and out["had_plan"] and out["plan_left"] == ""
    # The simulated pieces carry firmware ids; connecting re-pointed the bindings from the plan to them.
    assert {int(k) - J: v for k, v in out["live"].items()} == {int(k): v for k, v in out["planned"].items()}
    assert out["instructions"].splitlines()[1] == "host" and "drives bone" in out["instructions"]
    print(f"\nproposed device driven through the simulator: max bone error {out['max_error']:.4f}°")
    assert out["max_error"] < 0.5 and out["compared"] > 100 and out["corrupted"] > 0 and out["unsent"] <= 2
    assert out["followers"] == 16 - 4  # every non-root bone the device does not drive follows
    assert out["threads"] == []  # the session closed its simulator and reader


def test_zero_on_the_device_and_identify_blink(tmp_path):
    """*Zero Joints on Device and Calibrate* sends the firmware's zero command to every bound joint (their
    flash takes the readings as zero), waits for the acknowledgements and calibrates on the readings taken
    after; *Identify* blinks one joint's green LED on and off and leaves it off."""
    out = run_blender(
        """
        # The simulated device runs in this process: on a busy machine its thread may read two polls at once,
        # and the firmware ignores a poll that comes while it answers the last, with the command in it. A
        # reader that waits longer for each reply (as for an adapter that holds bytes back) sends no poll
        # before the last was answered.
        import functools
        from tangible import SerialReader
        device_session.SerialReader = functools.partial(SerialReader, reply_timeout=0.25)
        bind_bones({J + 11: "hand", J + 13: "index_1"})
        rng = np.random.default_rng(12)
        angles = rng.uniform(-0.5, 0.5, (4, 4))  # held still, in DEVICE.joints order
        simulator = Simulator(DEVICE, motion=lambda t: joint_rotation(angles), seed=2).start()
        settings.port = simulator.path
        bpy.ops.contact_edit.device_connect()
        reader = session().reader
        until(lambda s: all(s.components.get(j) is not None and s.components[j].rotation is not None
                            for j in (J + 11, J + 13)), "readings of the bound joints")
        before = {j: simulator.firmware(j).zero for j in (J + 11, J + 13, J + 14)}
        result_ = bpy.ops.contact_edit.device_calibrate(pose="REST", zero_device=True)
        after = {j: simulator.firmware(j).zero for j in (J + 11, J + 13, J + 14)}
        state = reader.state()
        zeroed = [before[j] != after[j] for j in (J + 11, J + 13)]
        untouched = before[J + 14] == after[J + 14]  # the unbound joint is left alone
        order = DEVICE.joints
        # The zeroed joints now read their proximal twist and both bends as zero (the firmware leaves the
        # distal twist's zero alone), within a few LSB of the 14-bit readings.
        straight = max(np.abs(state.components[j].angles[:3]).max() for j in (J + 11, J + 13))
        bpy.ops.contact_edit.device_update()
        at_rest = max(degrees(basis(BONES[j]), rot.IDENTITY) for j in (J + 11, J + 13))

        # The blink is timed by the session's clock: here one the script moves on by hand, a half period at
        # a time, with an update each (what the live timer does). The device shows each LED command the
        # session sends; the reader sends one lost on the way (see above) again when no ack comes, and the
        # script does too after 50 polls without it (a busy machine may lose all the reader's attempts).
        class Clock:
            now = 100.0
            @classmethod
            def monotonic(cls):
                return cls.now
        device_session.time = Clock
        commands, sent, send = reader.state().link.commands, [], reader.send
        def spy(command):
            sent.append(command)
            send(command)
        reader.send = spy
        bpy.ops.contact_edit.device_identify(joint=J + 13)
        greens, others, resent = [], [], 0
        for phase in range(2 * device_session.BLINKS + 2):
            Clock.now = 100.0 + (phase + 0.5) * device_session.BLINK_PERIOD / 2
            bpy.ops.contact_edit.device_update()
            green = sent[-1].params[2] == 1  # led(): blue, red, green
            give_up = time.monotonic() + WAIT
            while True:
                polls = reader.state().link.polls
                until(lambda s: simulator.firmware(J + 13).leds[1] == green or s.link.polls >= polls + 50,
                      "the LED command to show")
                if simulator.firmware(J + 13).leds[1] == green or time.monotonic() > give_up:
                    break
                send(sent[-1])
                resent += 1
            greens.append(simulator.firmware(J + 13).leds[1])
            others.append(any(simulator.firmware(j).leds[1] for j in DEVICE.joints if j != J + 13))
        device_session.time = time
        until(lambda s: s.link.commands == commands + len(sent) + resent, "every command sent")
        bpy.ops.contact_edit.device_stop()
        simulator.close()
        result(dict(finished=sorted(result_), zeroed=zeroed, untouched=untouched, straight=float(straight),
                    at_rest=at_rest, greens=greens, others=others, resent=resent,
                    sent=[c.encode().hex() for c in sent]))
        """,
        tmp_path,
        setup=SETUP,
    )
    assert out["finished"] == ["FINISHED"] and out["zeroed"] == [True, True] and out["untouched"]
    assert out["straight"] < 4 * 2 * np.pi / 16384  # a few 14-bit steps
    assert out["at_rest"] < 0.1
    # On and off BLINKS times, one LED command per half period, ending off (the closing "off" sent twice, in
    # case the device loses one); no other joint's LED lit.
    on, off = (
        Command.led(red=False, green=g, blue=False, target=J + 13).encode().hex() for g in (True, False)
    )
    assert out["sent"] == [on, off] * 4 + [off, off]
    assert out["greens"] == [True, False] * 4 + [False, False] and not any(out["others"])
    print(f"\nblinked; {out['resent']} lost LED commands sent again")


def test_an_unacknowledged_command_is_counted_and_the_session_stays_live(tmp_path):
    """A command nobody acknowledges (for an id no piece has: the firmware floods it down the tree and no
    piece runs it, ``main.c`` lines 461-476) is sent the reader's number of times and given up; the live
    session does not fail on it: it goes on driving the bone, and its status line counts the command."""
    out = run_blender(
        """
        import functools
        from tangible import Command, CommandError, SerialReader
        device_session.SerialReader = functools.partial(SerialReader, ack_timeout=0.05, attempts=2)
        bind_bones({J + 11: "hand"})
        simulator = Simulator(DEVICE, motion=RandomMotion(4, seed=7), seed=3).start()
        settings.port = simulator.path
        bpy.ops.contact_edit.device_connect()
        reader = session().reader
        delivery = reader.send(Command.led(red=False, green=True, blue=False, target=J + 99))
        try:
            delivery.wait(WAIT)
            error = ""
        except CommandError as err:
            error = str(err)
        turned = update_until_turned([J + 11], ["hand"], 1.0)["hand"]
        level = session().level
        status = settings.status
        link = session().state.link
        bpy.ops.contact_edit.device_stop()
        simulator.close()
        result(dict(error=error, attempts=delivery.attempts, turned=turned, level=level, status=status,
                    unacknowledged=link.unacknowledged, resent=link.resent))
        """,
        tmp_path,
        setup=SETUP,
    )
    assert "got no acknowledgement after 2 attempts" in out["error"] and out["attempts"] == 2
    assert out["unacknowledged"] == 1 and out["resent"] == 1
    assert out["turned"] > 1.0 and out["level"] == "INFO"
    assert "1 command to the device unacknowledged" in out["status"], out["status"]
