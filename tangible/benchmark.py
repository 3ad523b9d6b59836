"""Figures for the puppet device: the serial link under corruption, pose interpolation per frame, and the
error-vs-kit-size curve of the rig reduction (the paper's Fig. 7).

:func:`run` returns the timing rows and :func:`run_reduction_curve` the curve, both as
:class:`geodesics.benchmark.Row` for :func:`geodesics.benchmark.format_table`.
"""

from __future__ import annotations

import time
from collections import defaultdict, deque
from collections.abc import Callable, Mapping
from dataclasses import replace

import numpy as np

from geodesics.benchmark import Row, median_time

from . import rotations as rot
from .creatures import creature
from .device import SPLITTERS, DeviceTree, Piece
from .motions import RandomMotion
from .posespace import PoseSpace
from .protocol import CYCLE, MIN_ID, DataRecord, encode_record
from .puppet import JointBinding, Puppet
from .reader import SerialReader
from .reduction import Kit, reduce
from .simulator import Faults, Simulator
from .topology import DeviceTopology

__all__ = ["link_device", "run", "run_reduction_curve"]


def link_device(n_joints: int = 25) -> DeviceTree:
    """A branching test device: a spine of joints with a cross splitter, then arms and legs of joints
    under T and Y splitters and a trident; ``n_joints`` joints in all (at least 8). Ids are firmware ids,
    :data:`~tangible.protocol.MIN_ID` + 1, + 2, …"""
    pieces = [Piece(1, "joint"), Piece(2, "splitter", 1, 0, splitter=SPLITTERS["cross"])]
    hubs = [(2, 0), (2, 1), (2, 2)]
    nid = 3
    for kind in ("T", "Y", "trident"):
        parent, slot = hubs.pop(0)
        pieces += [
            Piece(nid, "joint", parent, slot),
            Piece(nid + 1, "splitter", nid, 0, splitter=SPLITTERS[kind]),
        ]
        hubs += [(nid + 1, s) for s in range(SPLITTERS[kind].valence)]
        nid += 2
    joints = sum(p.kind == "joint" for p in pieces)
    ends = {hub: hub for hub in hubs}
    i = 0
    while joints < n_joints:
        hub = hubs[i % len(hubs)]
        parent, slot = ends[hub]
        pieces.append(Piece(nid, "joint", parent, slot))
        ends[hub] = (nid, 0)
        nid += 1
        joints += 1
        i += 1
    return DeviceTree(
        replace(p, id=MIN_ID + p.id, parent=MIN_ID + p.parent if p.parent else 0) for p in pieces
    )


def _link(seconds: float, corrupt: float, say) -> list[Row]:
    device = link_device(25)
    n = len(device.joints)
    published: list[tuple[bytes, float]] = []
    sim = Simulator(device, motion=RandomMotion(n, seed=1), faults=Faults.corrupt(corrupt), seed=2)
    try:
        with SerialReader(sim.path, observer=lambda r, t: published.append((encode_record(r), t))) as reader:
            say(f"serial link: {n} joints and {len(device.splitters)} splitters for {seconds:.0f} s")
            sim.start()
            time.sleep(seconds)
            sim.stop()
            seen = -1
            while seen != reader.state().link.bytes:  # drain what was written
                seen = reader.state().link.bytes
                time.sleep(0.2)
            state = reader.state()
        origin = sim.clock_origin
    finally:
        sim.close()
    sent = [s for s in sim.history if s.record is not None]
    intact = [s for s in sent if s.intact]
    damaged = [s for s in sent if s.fault not in ("", "lose")]
    arrived: dict[bytes, deque[float]] = defaultdict(deque)
    for data, t in published:
        arrived[data].append(t)
    latency, age, lost = [], [], 0
    for s in intact:  # in the order they were written, as they were published
        times = arrived.get(encode_record(s.record))
        if not times:
            lost += 1
            continue
        t = times.popleft()
        latency.append(t - s.written)
        if s.sampled is not None:
            age.append(t - (origin + s.sampled))
    accepted = sum(len(q) for q in arrived.values())  # published, but never sent intact
    latency, age = np.array(latency), np.array(age)
    data = sum(isinstance(s.record, DataRecord) for s in intact)
    link = state.link
    return [
        Row(
            f"link latency, {n} joints on the firmware's {1e3 * CYCLE:.0f} ms poll cycle, "
            f"{100 * len(damaged) / max(1, len(sent)):.1f}% of records corrupted",
            float(np.median(latency)),
            note=(
                f"median {1e3 * np.median(latency):.3f} ms from a reply's last byte to the published state "
                f"(p99 {1e3 * np.percentile(latency, 99):.2f} ms); valid records lost: {lost} of "
                f"{len(intact)}; corrupted accepted: {accepted} of {len(damaged)}; "
                f"{link.polls / seconds:.0f} polls/s, {len(intact) / seconds:.0f} records/s, each joint's "
                f"data at {data / seconds / n:.0f} Hz, {1e3 * np.median(age):.0f} ms from sensor to state "
                f"(median, relayed hop by hop); reader counted {link.corrupt} corrupt, {link.short} short, "
                f"{link.missing} missing replies"
            ),
        )
    ]


def _interpolation(repeat: int, say) -> list[Row]:
    say("pose interpolation, 100-bone rig")
    sk, samples = creature(100, n_poses=12, seed=5)
    driven = np.array([1, 4, 8, 14, 22, 30, 41, 55, 70, 90])
    others = np.setdiff1d(np.arange(sk.n_bones), driven)
    space = PoseSpace(samples[:, driven], samples[:, others])
    rng = np.random.default_rng(0)
    a, b = rng.integers(0, len(samples), (2, 200))
    keys = rot.slerp(samples[a][:, driven], samples[b][:, driven], rng.uniform(0, 1, 200)[:, None])
    per_key = median_time(lambda: [space(k) for k in keys], repeat) / len(keys)
    rows = [
        Row(
            "pose interpolation per update, 100 bones (10 driven, 12 samples)",
            per_key,
            note="PCA 2-D, Delaunay, barycentric slerp of 90 bones",
        )
    ]
    # The whole per-frame evaluation an operator runs: state lookup, joint mapping, interpolation.
    topo = DeviceTopology()
    for i, _ in enumerate(driven):
        topo.observe(DataRecord(100 + i, 0 if i == 0 else 99 + i, 0, (0.1, 0.2, 0.3, 0.4)), 0.0)
    state = topo.snapshot(0.0)
    puppet = Puppet(sk, [JointBinding(100 + i, int(bone)) for i, bone in enumerate(driven)], samples=samples)
    per_eval = median_time(lambda: [puppet.evaluate(state) for _ in range(50)], repeat) / 50
    rows.append(
        Row(
            "Puppet.evaluate per frame, same rig, 10 live joints",
            per_eval,
            note="what a modal timer calls each tick",
        )
    )
    return rows


def run(
    repeat: int = 5,
    progress: Callable[[str], None] | None = None,
    *,
    seconds: float = 5.0,
    corrupt: float = 0.05,
) -> list[Row]:
    """The device figures: 25 joints of the simulated firmware polled over a pty on its 20 ms cycle with
    ``corrupt`` of the records damaged for ``seconds`` (valid records lost, latency from a reply's last
    byte to the published state), and pose interpolation per update for a 100-bone rig (median of
    ``repeat`` timed batches)."""
    say = progress or (lambda _msg: None)
    return _link(seconds, corrupt, say) + _interpolation(repeat, say)


def run_reduction_curve(
    n_bones: int = 110,
    kit_sizes: tuple[int, ...] = (0, 1, 2, 3, 4, 5, 6, 8, 10, 12),
    splitters: Mapping[str, int] | None = None,
    n_poses: int = 12,
    progress: Callable[[str], None] | None = None,
) -> list[Row]:
    """Pose error against the number of joints in the kit (Fig. 7): one row per kit size, the time to
    reduce in ``ours`` and the error (percent of a rigid device's) in the note."""
    say = progress or (lambda _msg: None)
    sk, samples = creature(n_bones, n_poses=n_poses, seed=0)
    splitters = dict(splitters) if splitters is not None else {"T": 1, "cross": 1}
    kinds = " + ".join(f"{c} {k}" for k, c in splitters.items()) or "no splitters"
    rows = []
    for k in kit_sizes:
        say(f"reduction: {n_bones} bones, {k} joints")
        start = time.perf_counter()
        r = reduce(sk, samples, Kit(k, splitters))
        seconds = time.perf_counter() - start
        bar = "#" * round(40 * r.relative_error)
        rows.append(
            Row(
                f"Fig. 7: {n_bones} bones, {n_poses} poses, {k:2d} joints + {kinds}",
                seconds,
                note=f"pose error {100 * r.relative_error:5.1f}% {bar}",
            )
        )
    return rows
