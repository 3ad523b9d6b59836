"""The modular puppet device (Glauser et al. 2016): protocol, serial reader, simulator, rig reduction,
pose-space interpolation, and the binding of a live device to a rig.

Device side:

* :mod:`tangible.protocol` — the published firmware's wire protocol (``PROTOCOL.md``): records and
  downlink :class:`~tangible.protocol.Command` s, CRC-8, the streaming
  :class:`~tangible.protocol.ReplyParser`.
* :class:`SerialReader` — a background thread polling the device over pyserial and publishing immutable
  :class:`DeviceState` snapshots, re-sending a command until it is acknowledged (:class:`Delivery`);
  :class:`DeviceTopology` — the parent→children table behind it.
* :class:`Simulator` — the firmware's state machines for a device tree, on a simulated clock, stepped by
  hand or in real time behind a pty, with faults on the host link; :mod:`tangible.firmware` is one
  controller's state machine, :mod:`tangible.motions` the joint motions that drive its sensors.
* :mod:`tangible.joint` — the two-ring universal joint: sensed angles ↔ rotation.

Rig side:

* :class:`Skeleton` — bones, rest frames, node weights (filled from a Blender armature or a
  ``solver.Rig``); sample poses are ``(p, b, 4)`` quaternions.
* :func:`tangible.reachability.fit` — Eq. 1/7 by Gauss–Newton in the exponential map;
  :func:`reduce` — greedy joints and the splitter integer program; :mod:`tangible.assembly` — the
  instructions as text (:func:`instructions_text`) and SVG, and the pieces' colours by name
  (:func:`colour_name`).
* :mod:`tangible.rigreducer` — the authors' RigReducer files (libigl ``.tgf``/``.dmat``): :func:`read_rig`,
  :func:`write_rig`, :func:`write_reduction`, :func:`read_reduction`.
* :class:`PoseSpace` — PCA/Delaunay/barycentric-slerp interpolation; :class:`Puppet` — joints to bones,
  joints to scalars (read through one of :data:`CHANNELS`), calibration, evaluation per frame.

Also :mod:`tangible.creatures` (procedural rigs with sample poses) and :mod:`tangible.benchmark` (the
link, interpolation and Fig. 7 figures). Quaternions are ``(w, x, y, z)`` throughout
(:mod:`tangible.rotations`).
"""

import logging

from . import protocol
from .assembly import colour_name, instructions_text
from .device import SPLITTERS, DeviceTree, Piece, SplitterType
from .errors import CommandError, DeviceError, ProtocolError, RecordError, RigError, TangibleError
from .joint import joint_angles, joint_rotation
from .motions import KeyframeMotion, RandomMotion
from .posespace import PoseSpace
from .protocol import Command
from .puppet import CHANNELS, JointBinding, Puppet, PuppetPose, ScalarBinding, match_device
from .reader import Delivery, SerialReader, list_ports
from .reduction import Kit, Reduction, reduce
from .rigreducer import read_reduction, read_rig, write_reduction, write_rig
from .simulator import Faults, Simulator
from .skeleton import Skeleton, area_weights
from .topology import ComponentState, DeviceState, DeviceTopology

# A library does not print: port trouble goes to the "tangible" loggers, silent unless the application
# configures logging.
logging.getLogger(__name__).addHandler(logging.NullHandler())

__all__ = [
    "CHANNELS",
    "SPLITTERS",
    "Command",
    "CommandError",
    "ComponentState",
    "Delivery",
    "DeviceError",
    "DeviceState",
    "DeviceTopology",
    "DeviceTree",
    "Faults",
    "JointBinding",
    "KeyframeMotion",
    "Kit",
    "Piece",
    "PoseSpace",
    "ProtocolError",
    "Puppet",
    "PuppetPose",
    "RandomMotion",
    "RecordError",
    "Reduction",
    "RigError",
    "ScalarBinding",
    "SerialReader",
    "Simulator",
    "Skeleton",
    "SplitterType",
    "TangibleError",
    "area_weights",
    "colour_name",
    "instructions_text",
    "joint_angles",
    "joint_rotation",
    "list_ports",
    "match_device",
    "protocol",
    "read_reduction",
    "read_rig",
    "reduce",
    "write_reduction",
    "write_rig",
]
