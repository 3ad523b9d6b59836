"""The exceptions of the tangible package.

Every error names what is wrong and where: the byte offset in a record, the component id, the bone.
Bone indices are also kept as arrays (``RigError.bones``) so that a user interface can select them.
"""

from __future__ import annotations

import numpy as np


class TangibleError(Exception):
    """Base class of every error the tangible package raises on purpose."""


class ProtocolError(TangibleError, ValueError):
    """The protocol API was misused: a record or command that cannot be encoded (an id or angle out of
    range, a wrong number of values) or a parser fed something other than bytes.

    The streaming :class:`tangible.protocol.ReplyParser` never raises this for bad *bytes*: corrupt input
    is counted, not raised.
    """


class RecordError(ProtocolError):
    """Bytes handed to :func:`tangible.protocol.decode_record` or :meth:`tangible.protocol.Command.decode`
    are not a valid record or command.

    Attributes
    ----------
    reason : str
        A short machine-readable cause: ``"length"``, ``"kind"`` (an unknown record kind), ``"crc"``,
        ``"field"`` (a value the firmware never sends).
    offset : int
        Byte offset of the problem in the record (17 for a record's CRC, 9 for a command's).
    """

    def __init__(self, message: str, *, reason: str, offset: int):
        super().__init__(message)
        self.reason = reason
        self.offset = offset


class DeviceError(TangibleError, RuntimeError):
    """A device cannot be used as asked: a port URL that pyserial does not understand, a simulator asked
    to unplug a port it does not own, or a connected device whose shape differs from the planned one."""


class CommandError(DeviceError):
    """A downlink command was not acknowledged: the reader sent it its number of attempts, waiting its ack
    timeout after each, and no acknowledgement came (or the reader was closed first).

    Raised by :meth:`tangible.reader.Delivery.wait`; the reader thread itself never raises it (it logs the
    failure and counts it in ``DeviceState.link``).

    Attributes
    ----------
    command : tangible.protocol.Command
    attempts : int
        How many times it was sent.
    """

    def __init__(self, message: str, *, command, attempts: int):
        super().__init__(message)
        self.command = command
        self.attempts = attempts


class RigError(TangibleError, ValueError):
    """A skeleton, its sample poses, a kit or a binding is not valid input.

    ``bones`` holds the indices of the offending bones (empty when they do not apply).
    """

    def __init__(self, message: str, *, bones=None):
        super().__init__(message)
        self.bones = (
            np.unique(np.asarray(bones, dtype=np.int64).ravel())
            if bones is not None
            else np.empty(0, np.int64)
        )
