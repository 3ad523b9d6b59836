"""A live puppet device driving one armature: the scene's bindings as a :class:`tangible.Puppet`, the
port or the built-in simulator, and :class:`Session`, which applies the device's latest state on each tick.
The operators that start, tick and stop sessions are in :mod:`.operators`.

Sessions are kept here (``sessions``) per armature *name* (never a Blender reference, so undo cannot leave
them dangling). A session owns the :class:`tangible.SerialReader` (and the :class:`tangible.Simulator`
behind it, if simulated) and the puppet. :meth:`Session.tick` applies the device's latest state once, on
the main thread: the bound bones take the joints' rotations, the other bones follow the sample poses by
pose interpolation, shape keys and properties take their joints' angles, and in record mode the pose is
keyed on every new frame. Joints that fall silent (unplugged, a subtree without power, the port gone) keep
their bones and numbers where they were — the pose freezes — and the status line says which; stopping
gives back what the device touched.
"""

from __future__ import annotations

import json
import time
from dataclasses import replace

import bpy
import numpy as np

from tangible import (
    SPLITTERS,
    Command,
    CommandError,
    DeviceError,
    DeviceState,
    DeviceTree,
    Faults,
    JointBinding,
    Piece,
    Puppet,
    PuppetPose,
    RandomMotion,
    ScalarBinding,
    SerialReader,
    Simulator,
    TangibleError,
    list_ports,
    match_device,
    protocol,
)

from ..bridge import BridgeError
from .bridge import (
    ArmatureRig,
    ScalarTarget,
    action_sample_poses,
    key_rotations,
    scalar_target,
    write_rotations,
)
from .properties import IDENTITY

#: Longest wait, when connecting, for the device to show every bound joint (the firmware's records climb
#: one piece per poll: a few hundred ms for 25 joints).
CONNECT_TIMEOUT = 1.5
#: The simulator's joints when nothing is bound or planned.
SIMULATED_JOINTS = 3
#: Longest wait, beyond the reader's own attempts, for joints to acknowledge a command (or to send
#: readings after it). The reader sends a command again when its ack does not come, ``attempts`` times
#: (:class:`tangible.SerialReader`).
ACK_TIMEOUT = 0.5
#: Identify blinks a joint's green LED (the one the firmware leaves as set: its main loop drives red and
#: blue itself) this many times, each half period on and half off.
BLINKS, BLINK_PERIOD = 4, 0.5


def device_armature(context) -> bpy.types.Object | None:
    """The armature the scene's device drives: the one chosen in the panel, else the active armature."""
    chosen = context.scene.contact_edit_device.armature
    if chosen is not None:
        return chosen
    obj = context.active_object
    return obj if obj is not None and obj.type == "ARMATURE" else None


def bindings_signature(settings) -> tuple:
    """Everything the puppet is built from, to notice when the user changes it."""
    action = settings.sample_action.name if settings.sample_action and settings.interpolate else ""
    return action, tuple(
        (b.joint, b.target, b.bone, b.object.name if b.object else "", b.shape_key, b.data_path, b.channel,
         b.source_min, b.source_max, b.target_min, b.target_max, *b.rest, *b.pose)
        for b in settings.bindings
    )  # fmt: skip


def build_puppet(settings, rig: ArmatureRig, armature: bpy.types.Object) -> tuple[Puppet, list[ScalarTarget]]:
    """The scene's bindings as a :class:`tangible.Puppet` on ``rig`` (with the sample poses, if any),
    and the numbers its scalar bindings drive.

    Raises
    ------
    BridgeError, TangibleError
        Naming the binding: an unknown bone or shape key, a bone or number bound twice, bad samples.
    """
    joints, scalars, targets = [], [], []
    bone_of: dict[int, int] = {}
    target_of: dict[str, int] = {}
    for i, b in enumerate(settings.bindings):
        where = f"binding {i + 1} (joint {b.joint})"
        if b.target == "BONE":
            bone = rig.bone(b.bone, where)
            if bone in bone_of:
                raise BridgeError(f"the bone '{b.bone}' is bound to joints {bone_of[bone]} and {b.joint}")
            bone_of[bone] = b.joint
            joints.append(JointBinding(b.joint, bone, rest=tuple(b.rest), pose=tuple(b.pose)))
            continue
        target = scalar_target(b)
        if target is None:
            raise BridgeError(f"{where} needs an object for its {b.target.lower().replace('_', ' ')}")
        target.check()
        if target.key in target_of:
            raise BridgeError(f"{target.label()} is driven by joints {target_of[target.key]} and {b.joint}")
        target_of[target.key] = b.joint
        source, value_range = (b.source_min, b.source_max), (b.target_min, b.target_max)
        scalars.append(ScalarBinding(b.joint, target.key, b.channel, source, value_range))
        targets.append(target)
    action = settings.sample_action if settings.interpolate else None
    samples = action_sample_poses(armature, action, rig) if action is not None and joints else None
    puppet = Puppet(rig.skeleton, joints, scalars, samples=samples, rest_pose=rig.start.rotations)
    return puppet, targets


def plan_json(device: DeviceTree) -> str:
    """A planned device as the scene stores it."""
    pieces = [
        {
            "id": p.id,
            "kind": p.kind,
            "parent": p.parent,
            "slot": p.slot,
            "colour": list(p.colour),
            "splitter": p.splitter.name if p.splitter is not None else None,
        }
        for p in device
    ]
    return json.dumps({"format": "contact-edit/device-plan", "version": 1, "pieces": pieces})


def plan_device(text: str) -> DeviceTree:
    """The planned device stored in the scene."""
    try:
        data = json.loads(text)
        pieces = [
            Piece(
                int(p["id"]),
                p["kind"],
                int(p["parent"]),
                int(p["slot"]),
                tuple(int(c) for c in p["colour"]),
                SPLITTERS[p["splitter"]] if p["splitter"] else None,
            )
            for p in data["pieces"]
        ]
    except (ValueError, KeyError, TypeError) as err:
        raise BridgeError(
            f"the scene's planned device is damaged ({err}); propose the device again"
        ) from None
    return DeviceTree(pieces)


def simulated_device(settings) -> DeviceTree:
    """What the built-in simulator emulates: the planned device (its pieces numbered from the firmware's
    first id, as real pieces would be; connecting maps the plan onto them), else a chain of the bound
    joints (or of a few joints when nothing is bound)."""
    if settings.plan:
        plan = plan_device(settings.plan)
        live = {p.id: protocol.MIN_ID + p.id for p in plan} | {0: 0}
        return DeviceTree(replace(p, id=live[p.id], parent=live[p.parent]) for p in plan)
    ids = list(dict.fromkeys(b.joint for b in settings.bindings))
    ids = ids or [protocol.MIN_ID + i for i in range(1, SIMULATED_JOINTS + 1)]
    return DeviceTree(Piece(j, "joint", ids[i - 1] if i else 0) for i, j in enumerate(ids))


# ---------------------------------------------------------------------------- the live session


class Session:
    """A device driving one armature.

    Parameters
    ----------
    rig : ArmatureRig
        The armature, captured at connect time (its channels are what :meth:`stop` gives back).
    reader : SerialReader
    simulator : Simulator or None
        The simulated device behind the reader's port, owned by the session.
    port : str
        What the status line calls the port.
    """

    def __init__(self, rig: ArmatureRig, reader: SerialReader, simulator: Simulator | None, port: str):
        self.rig = rig
        self.reader = reader
        self.simulator = simulator
        self.port = port
        self.puppet: Puppet | None = None
        self.targets: list[ScalarTarget] = []
        self.state: DeviceState | None = None
        self.pose: PuppetPose | None = None
        self.problem = ""
        self.level = "INFO"
        self._signature: tuple | None = None
        self._written = np.zeros(rig.skeleton.n_bones, bool)
        self._touched = np.zeros(rig.skeleton.n_bones, bool)
        self._saved_numbers: dict[str, tuple[ScalarTarget, float]] = {}
        self._applied: tuple | None = None
        self._keyed_frame: int | None = None
        self._blink: tuple[int, float, int] | None = None  # joint, start time, half period last sent

    @property
    def armature(self) -> str:
        return self.rig.armature

    @property
    def written_bones(self) -> tuple[str, ...]:
        """Bones the device poses: the bound ones and, with pose interpolation, every other non-root bone."""
        return tuple(n for n, w in zip(self.rig.names, self._written, strict=True) if w)

    def _rebind(self, settings, armature) -> None:
        signature = bindings_signature(settings)
        if signature == self._signature:
            return
        self._signature = signature
        self.puppet, self.targets, self.problem = None, [], ""
        self._written[:] = False
        try:
            puppet, targets = build_puppet(settings, self.rig, armature)
        except (BridgeError, TangibleError) as err:
            self.problem = f"Bindings not applied: {err}"
            return
        if puppet.joints or puppet.scalars:
            self.puppet, self.targets = puppet, targets
            self._written[[j.bone for j in puppet.joints]] = True
            if puppet.pose_space is not None:
                self._written |= self.rig.skeleton.parents >= 0

    def tick(self, scene) -> tuple[str, str]:
        """Apply the device's latest state to the armature once; key it if recording every frame.

        Returns
        -------
        (level, message)
            ``"INFO"`` while the device drives, ``"WARNING"`` when some or all of the pose is frozen
            (silent joints, the port lost) or the bindings cannot be applied; the message says which.

        Raises
        ------
        BridgeError
            If the armature or one of its driven bones is gone.
        """
        armature = self.rig.armature_object()
        settings = scene.contact_edit_device
        self._rebind(settings, armature)
        state = self.reader.state()
        self.state = state
        self._blink_step()
        frame = scene.frame_current
        applied = (state.version, self._signature, frame)
        if self.puppet is not None and applied != self._applied:
            pose = self.puppet.evaluate(state, self.pose)
            self._write(armature, pose)
            self.pose, self._applied = pose, applied
            if settings.record == "EVERY_FRAME" and frame != self._keyed_frame:
                self.key(scene)
        level, message = self._status(state)
        self.level = level
        if settings.status != message:
            settings.status = message
        return level, message

    def _write(self, armature, pose: PuppetPose) -> None:
        write_rotations(armature, self.written_bones, pose.rotations[self._written])
        self._touched |= self._written
        for target in self.targets:
            if target.key in pose.scalars:
                self._saved_numbers.setdefault(target.key, (target, target.get()))
                target.set(pose.scalars[target.key])

    def key(self, scene) -> int:
        """Key what the device poses at the current frame; returns how many bones and numbers were keyed."""
        if self.pose is None:
            raise DeviceError(
                "the device poses nothing yet, so there is nothing to key: bind its joints to bones, "
                "shape keys or properties in the Puppet Device panel first"
            )
        frame = scene.frame_current
        key_rotations(self.rig.armature_object(), self.written_bones, frame)
        for target in self.targets:
            target.keyframe(frame)
        self._keyed_frame = frame
        return len(self.written_bones) + len(self.targets)

    def identify(self, joint: int) -> None:
        """Blink ``joint``'s green LED (:data:`BLINKS` times, driven by :meth:`tick`) so the puppeteer can
        find it on the device.

        Raises
        ------
        DeviceError
            If the joint is not attached.
        """
        c = self.reader.state().components.get(joint)
        if c is None or not c.attached:
            raise DeviceError(f"joint {joint} is not attached, so it cannot blink")
        if self._blink is not None and self._blink[0] != joint:
            self.reader.send(Command.led(red=False, green=False, blue=False, target=self._blink[0]))
        self._blink = (joint, time.monotonic(), -1)
        self._blink_step()

    def _blink_step(self) -> None:
        """Send the LED command the blink calls for now, once per half period. A command can be lost (the
        firmware ignores a poll that comes while it is busy), so the closing "off" goes twice, a half
        period apart."""
        if self._blink is None:
            return
        joint, start, sent = self._blink
        phase = min(int((time.monotonic() - start) / (BLINK_PERIOD / 2)), 2 * BLINKS + 1)
        if phase != sent:
            on = phase < 2 * BLINKS and phase % 2 == 0
            self.reader.send(Command.led(red=False, green=on, blue=False, target=joint))
        self._blink = None if phase > 2 * BLINKS else (joint, start, phase)

    def zero(self, joints: list[int]) -> DeviceState:
        """Send the firmware's zero command (``'z'``: the joint stores its current readings as its zero, in
        flash) to each of ``joints`` and wait until each has acknowledged it and sent readings taken
        after; return that state.

        The reader sends them one at a time and sends each again when no acknowledgement comes: a piece
        writing its flash ignores polls (``Src/main.c``, ``SET_FLASH``), and one that has just restarted
        ignores the first (``bus.c`` lines 35–84), so a command that reaches it then is lost.

        Raises
        ------
        DeviceError
            Naming the joints that did not acknowledge after the reader's attempts.
        """
        reader = self.reader
        deliveries = [(j, reader.send(Command.zero(target=j))) for j in joints]
        deadline = time.monotonic() + len(joints) * reader.attempts * reader.ack_timeout + ACK_TIMEOUT
        silent = []
        for j, delivery in deliveries:
            try:
                ack = delivery.wait(max(0.0, deadline - time.monotonic()))
            except CommandError:
                ack = None
            if ack is None:
                silent.append(j)
        if silent:
            raise DeviceError(
                f"joints {', '.join(map(str, silent))} did not confirm zeroing after {reader.attempts} tries "
                "(those that did are zeroed on the device); the scene's calibration was not changed"
            )
        acked = {j: self.reader.state().components[j].data_time or -np.inf for j in joints}
        fresh = self.reader.wait_for(
            lambda s: all((s.components[j].data_time or -np.inf) > acked[j] for j in joints), ACK_TIMEOUT
        )
        if fresh is None:
            raise DeviceError("the zeroed joints sent no readings after; the calibration was not changed")
        return fresh

    def calibrate(self, settings, to_start: bool, zero_device: bool = False) -> int:
        """Take the device's current shape as the bound bones' rest pose (or, ``to_start``, as the pose the
        armature had before connecting): store each bone binding's reading and pose in the scene.

        With ``zero_device`` the joints first store this shape as their own zero (:meth:`zero`), so any
        host reads them straight in it; the readings taken after still become the rest (the firmware
        does not zero the distal twist of a two-controller joint, so they are not all exactly straight).

        Raises
        ------
        DeviceError
            Naming the bound joints that are not attached, or that did not confirm zeroing.
        """
        state = self.reader.state()
        bound = [b for b in settings.bindings if b.target == "BONE"]
        silent = sorted(
            {
                b.joint
                for b in bound
                if (c := state.components.get(b.joint)) is None or not c.attached or c.rotation is None
            }
        )
        if silent:
            raise DeviceError(
                f"joints {', '.join(map(str, silent))} are not attached, so they cannot be calibrated: "
                "plug them in (or unbind them) and hold the device still"
            )
        if not bound:
            raise DeviceError("no joint is bound to a bone, so there is nothing to calibrate")
        if zero_device:
            state = self.zero(sorted({b.joint for b in bound}))
        start = [self.rig.start.rotations[self.rig.bone(b.bone, f"joint {b.joint}")] for b in bound]
        for b, pose in zip(bound, start, strict=True):
            b.rest = tuple(state.components[b.joint].rotation)
            b.pose = tuple(pose) if to_start else IDENTITY
        return len(bound)

    def _status(self, state: DeviceState) -> tuple[str, str]:
        if not state.connected:
            return (
                "WARNING",
                f"Lost the port {self.port} ({state.link.error}): the pose is frozen; reconnecting…",
            )
        if self.problem:
            return "WARNING", self.problem
        attached = [c for c in state.attached if state.components[c].kind == "joint"]
        if self.puppet is None:
            return "INFO", (
                f"Connected to {self.port}: {len(attached)} joint{'s' * (len(attached) != 1)} attached; "
                "bind them to bones"
            )
        missing = sorted(self.puppet.missing(state))
        if missing:
            bound = {j.joint for j in self.puppet.joints} | {s.joint for s in self.puppet.scalars}
            if set(missing) >= bound:
                return "WARNING", f"The device on {self.port} is silent: the pose is frozen"
            return "WARNING", (
                f"Joint{'s' * (len(missing) > 1)} {', '.join(map(str, missing))} "
                f"({', '.join(self._driven_by(missing))}) fell silent: the pose is frozen there"
            )
        n_bound = len(self.puppet.joints)
        text = f"Live on {self.port}: {n_bound} bone{'s' * (n_bound != 1)} driven"
        followers = int(self._written.sum()) - n_bound
        if followers:
            text += f", {followers} following by interpolation"
        if self.targets:
            text += f", {len(self.targets)} number{'s' * (len(self.targets) != 1)}"
        damaged = state.link.corrupt + state.link.oversize
        if damaged:
            text += f"; {damaged} damaged record{'s' * (damaged != 1)} skipped"
        lost = state.link.unacknowledged
        if lost:  # sent the reader's number of times, never acknowledged (the reader logged each)
            text += f"; {lost} command{'s' * (lost != 1)} to the device unacknowledged"
        return "INFO", text

    def _driven_by(self, joints) -> list[str]:
        names = self.rig.names
        out = [f"'{names[j.bone]}'" for j in self.puppet.joints if j.joint in joints]
        keys = {s.name for s in self.puppet.scalars if s.joint in joints}
        return out + [t.label() for t in self.targets if t.key in keys]

    def stop(self, restore: bool = True) -> None:
        """Close the port (and the simulator); ``restore``: give the bones and numbers the device touched
        their values from before connecting."""
        self.reader.close()
        if self.simulator is not None:
            self.simulator.close()
        if not restore:
            return
        armature = bpy.data.objects.get(self.armature)
        if armature is not None and armature.type == "ARMATURE":
            self.rig.start.restore(armature, np.flatnonzero(self._touched))
        for target, value in self._saved_numbers.values():
            try:
                target.set(value)
            except BridgeError:
                continue  # the number is gone: nothing to give back


#: Live sessions by armature name.
sessions: dict[str, Session] = {}


def live_session(context) -> Session | None:
    """The session driving the scene's device armature, if any."""
    armature = device_armature(context)
    return sessions.get(armature.name) if armature is not None else None


def stop_all(restore: bool = True) -> None:
    """Stop every session (when the add-on is disabled or another file is loaded)."""
    while sessions:
        _, session = sessions.popitem()
        session.stop(restore)


def open_device(settings) -> tuple[SerialReader, Simulator | None, str]:
    """Open the scene's port, or start the simulator and open its pseudo-terminal.

    Raises
    ------
    BridgeError
        If the port cannot be opened, with the ports there are.
    """
    simulator = None
    if settings.simulator:
        device = simulated_device(settings)
        motion = RandomMotion(
            len(device.joints), seed=settings.simulator_seed, max_bend=np.radians(45), speed=0.5
        )
        faults = Faults.corrupt(settings.simulator_corruption / 100.0)
        simulator = Simulator(device, motion=motion, faults=faults, seed=settings.simulator_seed).start()
        url, port = simulator.path, "the simulator"
    else:
        url = settings.port.strip()
        if not url:
            raise BridgeError("choose the device's port first (or the simulator)")
        port = f"'{url}'"
    try:
        reader = SerialReader(url)
    except DeviceError as err:
        if simulator is not None:
            simulator.close()
        raise BridgeError(str(err)) from None
    if not reader.connected:
        error = reader.state().link.error
        reader.close()
        if simulator is not None:
            simulator.close()
        raise BridgeError(f"cannot open the port {port}: {error}. {_ports_hint()}")
    return reader, simulator, port


def _ports_hint() -> str:
    ports = [device for device, _ in list_ports()]
    found = f"Ports on this computer: {', '.join(ports)}" if ports else "No serial ports found"
    return f"{found}; or try the simulator"


def wait_for_device(
    reader: SerialReader, port: str, plan: DeviceTree | None, joints: set[int]
) -> dict[int, int]:
    """Wait until the device shows every bound joint (or the planned device) and return the planned piece →
    live id map (identity without a plan).

    Raises
    ------
    BridgeError
        Saying what arrived instead: nothing, bytes that are no device messages, another device.
    """
    matched: dict[int, int] = {}

    def ready(state: DeviceState) -> bool:
        if state.link.frames == 0:
            return False
        if plan is not None:
            try:
                matched.update(match_device(plan, state))
            except DeviceError:
                return False
        live = [matched.get(j, j) for j in joints]
        return all(
            (c := state.components.get(j)) is not None and c.attached and c.angles is not None for j in live
        )

    state = reader.wait_for(ready, CONNECT_TIMEOUT)
    if state is not None:
        return matched or {j: j for j in joints}
    state = reader.state()
    link = state.link
    if link.frames == 0:
        if link.bytes <= protocol.POLL_SIZE * link.echoes:  # at most our own polls, echoed by the adapter
            raise BridgeError(f"nothing arrives on {port}: is the device plugged in and powered?")
        raise BridgeError(
            f"{port} sends data, but no puppet device messages ({link.bytes} bytes, {link.corrupt} damaged "
            f"spots in {CONNECT_TIMEOUT:g} s): is it the right port?"
        )
    if plan is not None:
        try:
            match_device(plan, state)
        except DeviceError as err:
            raise BridgeError(f"the device on {port} is not assembled as proposed: {err}") from None
    heard = [c for c in state.attached if state.components[c].kind == "joint"]
    silent = sorted(j for j in joints if j not in heard)
    raise BridgeError(
        f"joint{'s' * (len(silent) > 1)} {', '.join(map(str, silent))} of the bindings "
        f"{'are' if len(silent) > 1 else 'is'} not attached to the device on {port} (attached joints: "
        f"{', '.join(map(str, heard)) or 'none'}): check the bindings and the device"
    )


@bpy.app.handlers.persistent
def _stop_before_load(*_args) -> None:
    stop_all(restore=False)


def register() -> None:
    """Stop the sessions when another file is loaded (their armatures go away)."""
    bpy.app.handlers.load_pre.append(_stop_before_load)


def unregister() -> None:
    if _stop_before_load in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.remove(_stop_before_load)
    stop_all()
