"""Binding a live device to a skeleton: joints to bones, joints to scalar properties, the rest by
pose-space interpolation. Everything a Blender operator needs between ``SerialReader.state()`` and
writing ``pose_bone.rotation_quaternion`` / ``key_block.value``, with no Blender in it.

A typical session::

    reduction = reduce(skeleton, samples, kit)                      # or bind by hand
    reader = SerialReader(port)                                     # or Simulator(...).path
    ids = match_device(reduction.device, reader.state())            # planned piece -> live id
    puppet = Puppet.from_reduction(reduction, ids, samples)
    puppet = puppet.calibrate(reader.state())                       # device held in the rest pose
    pose = puppet.evaluate(reader.state())                          # every timer tick
    pose.rotations  # (b, 4) local rotations; pose.scalars: {name: value}; pose.missing: joint ids

**Joint → bone.** A joint reading ``R`` (outlet frame in inlet frame, :mod:`tangible.joint`) drives bone
``b`` as ``Q_b = P · M⁻¹ · C⁻¹ · R · M`` where ``C`` is the reading at calibration (the ``rest`` of the
binding), ``P`` the bone's local rotation at calibration (identity when calibrating in the rest pose) and
``M`` the mount: the bone's axes in the joint's outlet frame (identity when the joint's shaft runs along
the bone's y axis, the convention of the reduction). So at calibration the bone is at ``P`` and every
later device rotation, expressed in the bone's frame, is applied on top.

**Joint → scalar** (the paper's face rig, Fig. 15): :class:`ScalarBinding` maps one channel of a joint —
a hinge, a ring, the total twist or the bend magnitude — linearly onto a property range, clamped.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from . import rotations as rot
from .device import DeviceTree
from .errors import DeviceError, RigError
from .joint import ANGLES, bend_angle
from .posespace import PoseSpace
from .skeleton import Skeleton
from .topology import DeviceState

__all__ = ["CHANNELS", "JointBinding", "Puppet", "PuppetPose", "ScalarBinding", "match_device"]

#: Joint channels a scalar can follow (radians).
CHANNELS = ("bend_a", "bend_b", "twist_proximal", "twist_distal", "twist", "bend")


def _quat(q, what: str) -> np.ndarray:
    a = np.asarray(q, dtype=np.float64)
    if a.shape != (4,) or not np.all(np.isfinite(a)) or not np.linalg.norm(a) > 0:
        raise RigError(f"{what} must be a finite non-zero quaternion (w, x, y, z), got {q!r}")
    a = rot.normalize(a)
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class JointBinding:
    """Device joint ``joint`` (component id) drives bone ``bone`` (index).

    Attributes
    ----------
    joint, bone : int
    rest : (4,) ndarray
        The joint's reading that corresponds to ``pose`` (set by :meth:`Puppet.calibrate`).
    pose : (4,) ndarray
        The bone's local rotation at calibration (identity: the rest pose).
    mount : (4,) ndarray
        The bone's axes in the joint's outlet frame.
    """

    joint: int
    bone: int
    rest: np.ndarray = field(default_factory=rot.IDENTITY.copy, compare=False)
    pose: np.ndarray = field(default_factory=rot.IDENTITY.copy, compare=False)
    mount: np.ndarray = field(default_factory=rot.IDENTITY.copy, compare=False)

    def __post_init__(self):
        for name in ("rest", "pose", "mount"):
            object.__setattr__(
                self, name, _quat(getattr(self, name), f"binding of joint {self.joint}: {name}")
            )

    def bone_rotation(self, reading) -> np.ndarray:
        """(..., 4) bone local rotations for joint readings ``reading`` (..., 4): the joint's rotations as
        unit quaternions (:func:`tangible.joint.joint_rotation` of the sensed angles, not the angles)."""
        return _bone_rotations(self.rest, self.pose, self.mount, reading)


def _bone_rotations(rest, pose, mount, reading) -> np.ndarray:
    """``pose · mount⁻¹ · rest⁻¹ · reading · mount``, batched over leading axes."""
    inner = rot.multiply(rot.conjugate(rest), reading)
    inner = rot.multiply(rot.multiply(rot.conjugate(mount), inner), mount)
    return rot.normalize(rot.multiply(pose, inner))


@dataclass(frozen=True)
class ScalarBinding:
    """Joint ``joint``'s ``channel`` (one of :data:`CHANNELS`) drives property ``name``: the channel's
    value in radians is mapped linearly from ``source`` to ``target`` and clamped to ``target``."""

    joint: int
    name: str
    channel: str = "bend_a"
    source: tuple[float, float] = (0.0, np.pi / 2)
    target: tuple[float, float] = (0.0, 1.0)

    def __post_init__(self):
        if self.channel not in CHANNELS:
            raise RigError(
                f"scalar {self.name!r}: channel must be one of {', '.join(CHANNELS)}, got {self.channel!r}"
            )
        if not (np.all(np.isfinite(self.source)) and self.source[0] != self.source[1]):
            raise RigError(f"scalar {self.name!r}: the source range needs two different finite angles")

    def value(self, angles) -> float:
        """The property value for sensed angles (4,), in record order (:data:`tangible.joint.ANGLES`)."""
        a = np.asarray(angles, dtype=np.float64)
        if self.channel == "twist":
            x = a[ANGLES.index("twist_proximal")] + a[ANGLES.index("twist_distal")]
        elif self.channel == "bend":
            x = float(bend_angle(a))
        else:
            x = a[ANGLES.index(self.channel)]
        u = (x - self.source[0]) / (self.source[1] - self.source[0])
        lo, hi = self.target
        return float(np.clip(lo + u * (hi - lo), min(lo, hi), max(lo, hi)))


@dataclass(frozen=True)
class PuppetPose:
    """One evaluation of a :class:`Puppet`.

    Attributes
    ----------
    rotations : (b, 4) ndarray
        Local rotations of every bone.
    driven : (b,) bool ndarray
        Bones set from a live joint reading.
    scalars : Mapping[str, float]
    missing : tuple of int
        Bound joints not attached (or never heard): their bones and scalars kept the previous values.
    """

    rotations: np.ndarray
    driven: np.ndarray
    scalars: Mapping[str, float]
    missing: tuple[int, ...]


class Puppet:
    """A device bound to a skeleton.

    Parameters
    ----------
    skeleton : Skeleton
    joints : sequence of JointBinding
        At most one binding per bone.
    scalars : sequence of ScalarBinding
    samples : (s, b, 4) array_like, optional
        Sample poses for pose-space interpolation of the bones no joint drives (keys: the bound bones'
        sample rotations). Without samples those bones stay at ``rest_pose``.
    rest_pose : (b, 4) array_like, optional
        Rotations of undriven bones without interpolation, and before the first evaluation (identity).
    """

    def __init__(
        self,
        skeleton: Skeleton,
        joints: Sequence[JointBinding],
        scalars: Sequence[ScalarBinding] = (),
        samples=None,
        rest_pose=None,
    ):
        self.skeleton = skeleton
        self.joints = tuple(joints)
        self.scalars = tuple(scalars)
        bones = [j.bone for j in self.joints]
        for b in bones:
            skeleton.bone_index(b)
        if len(set(bones)) != len(bones):
            raise RigError(
                "two joints are bound to the same bone", bones=[b for b in bones if bones.count(b) > 1]
            )
        self._bones = np.array(bones, dtype=np.int64)
        self._rest, self._pose, self._mount = (
            np.array([getattr(j, name) for j in self.joints]).reshape(-1, 4)
            for name in ("rest", "pose", "mount")
        )
        self._others = np.setdiff1d(np.arange(skeleton.n_bones), self._bones)
        n = skeleton.n_bones
        self.rest_pose = skeleton.check_poses(
            np.broadcast_to(rot.IDENTITY, (n, 4)) if rest_pose is None else rest_pose, "rest_pose"
        )
        self._samples = None if samples is None else skeleton.check_poses(samples, "samples")
        self.pose_space = (
            PoseSpace(self._samples[:, self._bones], self._samples[:, self._others])
            if self._samples is not None and self._bones.size and self._others.size
            else None
        )

    @classmethod
    def from_reduction(cls, reduction, ids: Mapping[int, int] | None = None, samples=None) -> Puppet:
        """Bind as a :class:`~tangible.reduction.Reduction` proposes: each planned joint piece to its
        bone, with the planned rest reading; ``ids`` maps planned piece ids to live component ids
        (:func:`match_device`; identity if omitted)."""
        ids = ids or {p: p for p in reduction.device.joints}
        joints = [
            JointBinding(int(ids[p]), int(reduction.bones[p]), rest=reduction.rest[p])
            for p in reduction.device.joints
        ]
        return cls(reduction.skeleton, joints, samples=samples)

    def _replace_joints(self, joints: Sequence[JointBinding]) -> Puppet:
        return Puppet(self.skeleton, joints, self.scalars, self._samples, self.rest_pose)

    def calibrate(self, state: DeviceState, pose=None) -> Puppet:
        """A new puppet whose joints read their current rotations as the bones' ``pose`` (b, 4) (default:
        the rest pose) — hold the device like the character and call this.

        Raises
        ------
        DeviceError
            Naming bound joints that are detached or have sent no data.
        """
        P = None if pose is None else self.skeleton.check_poses(pose, "calibration pose")
        self._require(state)
        out = []
        for j in self.joints:
            target = rot.IDENTITY if P is None else P[j.bone]
            out.append(replace(j, rest=state.components[j.joint].rotation, pose=target))
        return self._replace_joints(out)

    def _require(self, state: DeviceState) -> None:
        missing = self.missing(state)
        if missing:
            raise DeviceError(f"joints {list(missing)} are not attached or have sent no data")

    def missing(self, state: DeviceState) -> tuple[int, ...]:
        """Bound joint ids (bones or scalars) that are detached or have no data in ``state``."""
        ids = [j.joint for j in self.joints] + [s.joint for s in self.scalars]
        return tuple(
            dict.fromkeys(
                i
                for i in ids
                if (c := state.components.get(i)) is None or not c.attached or c.rotation is None
            )
        )

    def evaluate(self, state: DeviceState, previous: PuppetPose | None = None) -> PuppetPose:
        """The pose the device asks for.

        Live joints set their bones; detached joints keep their bones (and scalars) from ``previous``
        (or the rest pose); bones no joint drives follow the pose space, keyed by the driven bones.
        """
        missing = self.missing(state)
        R = self.rest_pose.copy() if previous is None else previous.rotations.copy()
        driven = np.zeros(self.skeleton.n_bones, bool)
        live = np.array([j.joint not in missing for j in self.joints], dtype=bool)
        if live.any():
            readings = np.array(
                [state.components[j.joint].rotation for j, ok in zip(self.joints, live, strict=True) if ok]
            )
            bones = self._bones[live]
            R[bones] = _bone_rotations(self._rest[live], self._pose[live], self._mount[live], readings)
            driven[bones] = True
        if self.pose_space is not None:
            R[self._others] = self.pose_space(R[self._bones])
        scalars = dict(previous.scalars) if previous is not None else {}
        for s in self.scalars:
            if s.joint not in missing:
                scalars[s.name] = s.value(state.components[s.joint].angles)
        return PuppetPose(R, driven, scalars, missing)


def match_device(plan: DeviceTree, state: DeviceState) -> dict[int, int]:
    """Pair a planned device with the attached one by shape: piece kinds and slots from the host down.
    Live pieces the plan does not use are ignored (they are simply not bound).

    Returns
    -------
    dict
        Planned piece id → live component id.

    Raises
    ------
    DeviceError
        At the first difference, naming the planned piece and slot.
    """
    out: dict[int, int] = {}

    def live_children(cid: int) -> dict[int, int]:
        return {state.components[c].slot: c for c in state.children.get(cid, ())}

    stack = [(0, 0)]
    while stack:
        planned, live = stack.pop()
        want = {p.slot: p for p in plan.children(planned)}
        have = live_children(live)
        where = "the host" if planned == 0 else f"planned piece {planned} (live {live})"
        for slot, piece in sorted(want.items()):
            cid = have.get(slot)
            if cid is None:
                raise DeviceError(
                    f"{where} should have a {piece.kind} in slot {slot}, but nothing is attached there"
                )
            kind = state.components[cid].kind
            if kind is not None and kind != piece.kind:
                raise DeviceError(f"{where} should have a {piece.kind} in slot {slot}, found {kind} {cid}")
            if piece.kind == "splitter" and piece.splitter is not None:
                slots = state.components[cid].slot_rotations
                if slots is not None and len(slots) != piece.splitter.valence:
                    raise DeviceError(
                        f"{where}, slot {slot}: planned splitter {piece.splitter.name!r} has "
                        f"{piece.splitter.valence} slots, live splitter {cid} has {len(slots)}"
                    )
            out[piece.id] = cid
            stack.append((piece.id, cid))
    return out
