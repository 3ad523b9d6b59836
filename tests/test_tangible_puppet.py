"""Binding a device to a rig: joints to bones, joints to scalars, calibration, and the whole chain from
a reduction through the simulated device back to the rig's pose."""

import numpy as np
import pytest

from tangible import (
    SPLITTERS,
    DeviceTopology,
    DeviceTree,
    JointBinding,
    KeyframeMotion,
    Kit,
    Piece,
    Puppet,
    ScalarBinding,
    Simulator,
    joint_angles,
    joint_rotation,
    match_device,
    reduce,
)
from tangible import rotations as rot
from tangible.creatures import creature
from tangible.errors import DeviceError, RigError
from tangible.protocol import MIN_ID, NODE_JOINT_TUT_TU, DataRecord, InitRecord, ReplyParser

HALF_DEGREE = np.radians(0.5)


def state_with(readings: dict, now=0.0, parents=None):
    """A DeviceState where joint id -> angles (4,), all plugged in a chain under the host."""
    topo = DeviceTopology()
    parents = parents or {}
    previous = 0
    for cid, angles in readings.items():
        parent = parents.get(cid, previous)
        topo.observe(InitRecord(cid, parent, 0, NODE_JOINT_TUT_TU, (1, 2, 3)), now)
        topo.observe(DataRecord(cid, parent, 0, tuple(angles)), now)
        previous = cid
    return topo.snapshot(now)


def polled_state(sim: Simulator, seconds: float):
    """The table a host builds polling the simulated device for ``seconds`` (simulated time)."""
    topo, parser = DeviceTopology(), ReplyParser()
    for t, poll, data in sim.polled(seconds):
        for m in parser.poll(poll) + parser.feed(data):
            topo.observe(m, t)
    sim.close()
    return topo.snapshot(sim.time)


def test_binding_maps_readings_relative_to_calibration():
    rng = np.random.default_rng(0)
    rest, mount, pose = rot.normalize(rng.normal(size=(3, 4)))
    b = JointBinding(7, 3, rest=rest, pose=pose, mount=mount)
    assert rot.angle(b.bone_rotation(rest), pose) < 1e-12
    R = rot.normalize(rng.normal(size=(10, 4)))
    expect = rot.multiply(
        pose, rot.multiply(rot.conjugate(mount), rot.multiply(rot.multiply(rot.conjugate(rest), R), mount))
    )
    assert rot.angle(b.bone_rotation(R), expect).max() < 1e-12
    with pytest.raises(RigError, match="rest"):
        JointBinding(1, 0, rest=[0, 0, 0, 0])


@pytest.mark.parametrize(
    ("channel", "angles", "value"),
    [
        ("bend_a", [0, 0.5, 0, 0], 0.5 / (np.pi / 2)),
        ("bend_b", [0, 0, -0.5, 0], 0.0),  # clamped at the bottom of the target range
        ("twist", [0.4, 0, 0, 0.4], 0.8 / (np.pi / 2)),
        ("bend", [2.0, 0.3, 0.4, 1.0], np.arccos(np.cos(0.3) * np.cos(0.4)) / (np.pi / 2)),
        ("twist_distal", [0, 0, 0, 3.0], 1.0),  # clamped at the top
    ],
)
def test_a_joint_channel_drives_a_scalar_like_a_shape_key(channel, angles, value):
    s = ScalarBinding(4, 'key_blocks["Smile"].value', channel=channel)
    assert s.value(angles) == pytest.approx(value)


def test_scalar_binding_rejects_unknown_channels():
    with pytest.raises(RigError, match="channel"):
        ScalarBinding(1, "x", channel="roll")


def test_calibrate_then_evaluate_and_freeze_missing_joints():
    sk, samples = creature(20, n_poses=6, seed=1)
    puppet = Puppet(
        sk,
        [JointBinding(11, 2), JointBinding(12, 9)],
        scalars=[ScalarBinding(12, "smile", "bend_a", (0.0, 1.0), (0.0, 1.0))],
        samples=samples,
    )
    at_rest = {11: [0.5, 0.2, 0.1, 0.0], 12: [0.0, -0.3, 0.2, 1.0]}  # record order
    puppet = puppet.calibrate(state_with(at_rest))
    first = puppet.evaluate(state_with(at_rest))
    assert rot.angle(first.rotations[[2, 9]], rot.IDENTITY).max() < 1e-9
    assert first.driven[[2, 9]].all() and first.driven.sum() == 2 and first.missing == ()
    moved = {11: [0.5, 0.6, 0.1, 0.0], 12: [0.0, -0.1, 0.2, 1.0]}
    pose = puppet.evaluate(state_with(moved), previous=first)
    expect = rot.multiply(rot.conjugate(joint_rotation(at_rest[11])), joint_rotation(moved[11]))
    assert rot.angle(pose.rotations[2], expect) < 1e-9
    assert pose.scalars["smile"] == pytest.approx(0.0)  # clamped: bend_a -0.1
    # Joint 12 detached: its bone and scalar keep their last values, and the pose says so.
    later = puppet.evaluate(state_with({11: moved[11]}), previous=pose)
    assert later.missing == (12,)
    assert rot.angle(later.rotations[9], pose.rotations[9]) < 1e-12
    assert later.scalars == pose.scalars
    with pytest.raises(DeviceError, match="12"):
        puppet.calibrate(state_with({11: moved[11]}))


def test_bones_no_joint_drives_follow_the_pose_space():
    sk, samples = creature(30, n_poses=8, seed=3)
    driven = [1, 5, 12, 20]
    puppet = Puppet(sk, [JointBinding(100 + i, b) for i, b in enumerate(driven)], samples=samples)
    for s in range(len(samples)):
        readings = {100 + i: joint_angles(samples[s, b]) for i, b in enumerate(driven)}
        pose = puppet.evaluate(state_with(readings))
        # Device readings equal to a sample's driven rotations give back the whole sample pose.
        assert rot.angle(pose.rotations, samples[s]).max() < 1e-3


def test_match_device_pairs_pieces_by_shape_and_names_differences():
    plan = DeviceTree(
        [
            Piece(1, "joint"),
            Piece(2, "splitter", 1, 0, splitter=SPLITTERS["T"]),
            Piece(3, "joint", 2, 0),
            Piece(4, "joint", 2, 1),
        ]
    )
    L = MIN_ID  # live pieces carry firmware ids
    live = DeviceTree(
        [
            Piece(L + 901, "joint"),
            Piece(L + 902, "splitter", L + 901, 0, splitter=SPLITTERS["T"]),
            Piece(L + 904, "joint", L + 902, 1),
            Piece(L + 903, "joint", L + 902, 0),
            Piece(L + 905, "joint", L + 903, 0),  # an extra piece the plan does not use
        ]
    )
    state = polled_state(Simulator(live, seed=0), 1.0)
    assert match_device(plan, state) == {1: L + 901, 2: L + 902, 3: L + 903, 4: L + 904}
    wrong = DeviceTree([Piece(1, "joint"), Piece(2, "joint", 1), Piece(3, "joint", 2)])
    with pytest.raises(
        DeviceError,
        match=rf"planned piece 1 \(live {L + 901}\) should have a joint in slot 0, found splitter {L + 902}",
    ):
        match_device(wrong, state)


def test_from_reduction_to_the_rig_through_the_simulated_device():
    """Plan a device, pose the simulated device as the plan's fit of a sample pose, read it back, bind
    it, and get the fitted bone rotations (within the device's accuracy)."""
    sk, samples = creature(29, n_poses=8, seed=0)
    r = reduce(sk, samples, Kit(5, {"T": 1}))
    s = 4
    joints = r.device.joints
    readings = rot.multiply(np.array([r.rest[p] for p in joints]), r.rotations[s])  # R = rest · Q
    offset = {p.id: p.id + MIN_ID + 1000 for p in r.device} | {0: 0}
    live = DeviceTree(
        Piece(offset[p.id], p.kind, offset[p.parent], p.slot, p.colour, p.splitter) for p in r.device
    )
    state = polled_state(Simulator(live, motion=KeyframeMotion([0.0], readings[None]), seed=1), 1.0)
    ids = match_device(r.device, state)
    assert ids == {p.id: offset[p.id] for p in r.device}
    puppet = Puppet.from_reduction(r, ids, samples)
    pose = puppet.evaluate(state)
    bones = [r.bones[p] for p in joints]
    assert rot.angle(pose.rotations[bones], r.rotations[s]).max() < HALF_DEGREE
    # The interpolated remainder brings the whole pose closer to the sample than the rigid device does.
    e_full = sk.forward(pose.rotations).tails - sk.forward(samples[s]).tails
    e_rigid = r.pose_energy[s] * sk.weights.sum() * sk.size**2
    assert np.einsum("mi,mi,m->", e_full, e_full, sk.weights) < e_rigid
