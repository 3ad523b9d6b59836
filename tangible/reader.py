"""The host side of the link: a background thread that polls the device over pyserial and publishes its
state.

::

    with SerialReader("/dev/ttyUSB0") as reader:        # or "loop://", "socket://host:port", a pty path
        state = reader.state()                          # immutable DeviceState, safe from any thread
        rotations = state.joint_rotations(state.attached)
        reader.send(Command.led(red=False, green=True, blue=False, target=joint_id))

The firmware only speaks when spoken to, so the reader thread opens the port at 230400 baud 8N1
(:data:`tangible.protocol.BAUDRATE`) and, every :data:`~tangible.protocol.CYCLE` (20 ms, well within the
250 ms after which an unpolled piece resets), writes a poll — ``b"R"`` and the next queued
:class:`~tangible.protocol.Command`, or the empty one — then reads the reply until its 216 bytes are in or
``reply_timeout`` has passed, and the rest of the cycle for stray bytes.

Commands wait for their acknowledgement, one at a time, in order (stop-and-wait). The firmware acks every
command it runs (``main.c`` lines 706–718) but sends nothing when it loses one, and it does lose them: a
piece ignores the first poll after it starts, the command in it too (``bus.c`` lines 35–84 set the
direction and return), which after a splitter's watchdog restart (``main.c`` lines 298–314: unpolled, or
no child heard, for 250 ms) is any poll; and it ignores polls while it writes its flash. So a command whose
ack has not come ``ack_timeout`` after it was sent is sent again, :data:`ATTEMPTS` times in all; one that
never got an ack is given up, logged, counted in ``state().link.unacknowledged`` (with
``link.command_error`` in words) and reported by its :class:`Delivery`, whose :meth:`~Delivery.wait`
raises :class:`~tangible.errors.CommandError`. Sending a command twice is harmless: every command the
firmware knows sets a state (``utility.c``, ``process_uart_command``). Everything read goes through a
:class:`~tangible.protocol.ReplyParser` (told of each poll, so it skips an adapter's echo of it and knows
where the reply starts) into a :class:`~tangible.topology.DeviceTopology`, under a lock, stamped with the
clock time the bytes arrived. If the port fails (unplugged, the pty's other end closed) the reader closes
it, marks the state disconnected and reopens it with exponential backoff; pieces keep their last data and
go detached by the usual timeout. Nothing is printed; port trouble is logged to the ``tangible.reader``
logger and shown in ``state().link.error``.

On a USB adapter, set its latency timer low (FTDI: 1 ms; the default 16 ms holds a reply's last bytes
back past the cycle).
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections import deque
from collections.abc import Callable

import serial
from serial.tools import list_ports as _list_ports

from .errors import CommandError, DeviceError, ProtocolError
from .protocol import (
    BAUDRATE,
    BROADCAST_ID,
    CYCLE,
    EMPTY,
    AckRecord,
    Command,
    ParserStats,
    Record,
    ReplyParser,
    poll_bytes,
)
from .topology import DETACH_TIMEOUT, DeviceState, DeviceTopology, LinkStats

__all__ = ["ACK_TIMEOUT", "ATTEMPTS", "Delivery", "SerialReader", "list_ports"]

log = logging.getLogger(__name__)

#: Times a command is sent in all (the first and two more) before the reader gives up on its ack.
ATTEMPTS = 3
#: Seconds the reader waits for a command's ack before sending it again. An ack takes about two polls
#: (40 ms) from the piece on the host, one more hop per poll each way from deeper pieces: about 0.3 s to
#: the far end of a T splitter with arms of three joints, 0.65 s to the end of a chain of 12 joints (1.5 s
#: for 25: raise it for such chains, or a slow ack just costs a harmless second copy).
ACK_TIMEOUT = 1.0


class Delivery:
    """What became of one command given to :meth:`SerialReader.send` (thread-safe).

    ``status`` is ``"queued"`` (not sent yet), ``"sent"`` (waiting for its ack), ``"acknowledged"``,
    ``"failed"`` (no ack after ``attempts`` sends, or the reader closed first; ``error`` says which) or,
    for the empty command, which the firmware never acknowledges (``main.c`` line 452), ``"sent"`` and
    done as soon as it is written. ``ack`` is the acknowledgement once it came.
    """

    def __init__(self, command: Command):
        self.command = command
        self.status = "queued"
        self.attempts = 0
        self.ack: AckRecord | None = None
        self.error = ""
        self._key = command.encode()[:8]  # an ack carries the command's bytes 0-7 (main.c 715)
        self._deadline = 0.0
        self._done = threading.Event()

    @property
    def done(self) -> bool:
        """Whether it was acknowledged or given up (or, empty, sent)."""
        return self._done.is_set()

    def wait(self, timeout: float | None = None) -> AckRecord | None:
        """Block until it is done, up to ``timeout`` seconds of wall time (None: until done); return the
        acknowledgement (None for the empty command, or if still waiting after ``timeout``).

        Raises
        ------
        CommandError
            If it failed: not acknowledged after the reader's attempts, or the reader was closed first.
        """
        self._done.wait(timeout)
        if self.status == "failed":
            raise CommandError(self.error, command=self.command, attempts=self.attempts)
        return self.ack

    def _finish(self, status: str, ack: AckRecord | None = None, error: str = "") -> None:
        self.status, self.ack, self.error = status, ack, error
        self._done.set()

    def __repr__(self) -> str:
        return f"Delivery({self.command!r}, status={self.status!r}, attempts={self.attempts})"


def list_ports() -> list[tuple[str, str]]:
    """Serial ports on this machine as ``(device, description)`` pairs, USB ones first — what a port
    menu offers (a :class:`~tangible.simulator.Simulator`'s ``path`` can be offered beside them)."""
    ports = sorted(_list_ports.comports(), key=lambda p: (p.vid is None, p.device))
    return [(p.device, p.description if p.description != "n/a" else p.device) for p in ports]


class SerialReader:
    """Poll a device on a serial port in a background thread and publish its latest state.

    Parameters
    ----------
    url : str
        Port name or pyserial URL (``"/dev/ttyUSB0"``, ``"COM3"``, ``"loop://"``, ``"socket://h:p"``).
    timeout : float
        Seconds of silence after which a component and its subtree are detached (2 s, Appendix A).
    period : float
        Seconds between polls (the firmware's cycle, 20 ms).
    reply_timeout : float
        Longest wait for a reply's 216 bytes after a poll (the device's take 10 ms); the next poll waits
        for the reply or this timeout, whichever comes first, and for ``period``. Raise it for an adapter
        that holds bytes back longer.
    read_timeout : float
        Longest a single blocking read waits; bounds how late a poll can be and how quickly :meth:`close`
        returns.
    ack_timeout : float
        Seconds to wait for a command's acknowledgement before sending it again (:data:`ACK_TIMEOUT`).
    attempts : int
        Times a command is sent in all before it is given up (:data:`ATTEMPTS`).
    backoff : (float, float)
        First and longest wait between attempts to reopen a failed port (doubling in between).
    open_port : callable, optional
        ``open_port(url) -> serial.SerialBase``; by default ``serial.serial_for_url`` at
        :data:`~tangible.protocol.BAUDRATE` 8N1 with ``read_timeout``.
    observer : callable, optional
        ``observer(record, time)`` is called on the reader thread for every record, right after it was
        published, with the clock time of publication. For instrumentation and recording; it must be quick
        and must not call back into the reader. Its exceptions are logged, not raised.
    clock : callable
        Monotonic clock in seconds (``time.monotonic``); all timestamps in the state come from it.
    start : bool
        Start the thread now (otherwise call :meth:`start`).

    Raises
    ------
    DeviceError
        If pyserial does not understand ``url`` at all. A port that merely does not exist yet is retried.
    """

    def __init__(
        self,
        url: str,
        *,
        timeout: float = DETACH_TIMEOUT,
        period: float = CYCLE,
        reply_timeout: float = CYCLE,
        read_timeout: float = 0.002,
        ack_timeout: float = ACK_TIMEOUT,
        attempts: int = ATTEMPTS,
        backoff: tuple[float, float] = (0.05, 1.0),
        open_port: Callable[[str], serial.SerialBase] | None = None,
        observer: Callable[[Record, float], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
        start: bool = True,
    ):
        if not (period > 0 and reply_timeout > 0 and read_timeout > 0 and ack_timeout > 0):
            raise DeviceError(
                f"period, reply_timeout, read_timeout and ack_timeout must be positive, got {period!r}, "
                f"{reply_timeout!r}, {read_timeout!r}, {ack_timeout!r}"
            )
        if isinstance(attempts, bool) or not isinstance(attempts, int) or attempts < 1:
            raise DeviceError(f"attempts must be a whole number of at least 1, got {attempts!r}")
        self.url = url
        self._period = float(period)
        self._reply_timeout = float(reply_timeout)
        self._read_timeout = float(read_timeout)
        self.ack_timeout = float(ack_timeout)
        self.attempts = attempts
        self._backoff = (float(backoff[0]), float(backoff[1]))
        self._open = open_port or self._default_open
        self._observer = observer
        self._clock = clock
        self._parser = ReplyParser()
        self._topology = DeviceTopology(timeout)
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._commands: deque[Delivery] = deque()
        self._waiting: Delivery | None = None  # sent, its ack not yet in
        self._sent = self._resent = self._unacknowledged = 0
        self._command_error = ""
        self._port: serial.SerialBase | None = None
        self._reconnects = 0
        self._failed = False
        self._error = ""
        self._stats = ParserStats()
        self._thread = threading.Thread(target=self._run, name="tangible-reader", daemon=True)
        try:
            self._try_open()
        except ValueError as e:
            raise DeviceError(f"cannot use serial port {url!r}: {e}") from None
        if start:
            self.start()

    def _default_open(self, url: str) -> serial.SerialBase:
        return serial.serial_for_url(
            url, baudrate=BAUDRATE, bytesize=8, parity="N", stopbits=1, timeout=self._read_timeout
        )

    def start(self) -> None:
        """Start the reader thread (once)."""
        if not self._thread.is_alive() and not self._stop.is_set():
            self._thread.start()

    # ------------------------------------------------------------------ the thread

    def _try_open(self) -> bool:
        try:
            port = self._open(self.url)
        except (serial.SerialException, OSError) as e:
            with self._cond:
                self._error = str(e)
                self._failed = True
            return False
        with self._cond:
            self._port = port
            if self._failed:
                self._reconnects += 1
            self._error = ""
        log.info("opened %s", self.url)
        return True

    def _lost(self, error: Exception) -> None:
        log.warning("lost %s: %s", self.url, error)
        self._publish(self._parser.close(), self._clock())
        with self._cond:
            port, self._port = self._port, None
            self._failed = True
            self._error = str(error)
            self._cond.notify_all()
        with contextlib.suppress(serial.SerialException, OSError):
            port.close()

    def _publish(self, records: list[Record], now: float) -> None:
        with self._cond:
            for r in records:
                self._topology.observe(r, now)
                w = self._waiting
                if w is not None and isinstance(r, AckRecord) and r.command == w._key:
                    self._waiting = None
                    w._finish("acknowledged", r)
            self._stats = self._parser.stats.copy()
            self._cond.notify_all()
        if self._observer is not None and records:
            published = self._clock()
            for r in records:
                try:
                    self._observer(r, published)
                except Exception:
                    log.exception("observer failed on %r", r)

    def _read(self, port: serial.SerialBase, until: float, reply: bool) -> None:
        """Read until clock time ``until`` (or, with ``reply``, until the reply is complete)."""
        while not self._stop.is_set() and self._clock() < until:
            if reply and self._parser.complete:
                return
            data = port.read(port.in_waiting or 1)
            if data:
                self._publish(self._parser.feed(data), self._clock())

    def _cycle(self, port: serial.SerialBase) -> None:
        """One poll: write it, read the reply, wait out the cycle."""
        start = self._clock()
        waiting = port.in_waiting
        if waiting:
            self._publish(self._parser.feed(port.read(waiting)), self._clock())
        with self._cond:
            delivery = self._next_command(start)
        command = delivery.command if delivery is not None else None
        poll = poll_bytes(command)
        self._publish(self._parser.poll(poll), self._clock())
        port.write(poll)
        if delivery is not None:
            written = self._clock()
            with self._cond:
                delivery.attempts += 1
                if delivery.attempts == 1:
                    self._sent += 1
                else:
                    self._resent += 1
                if delivery.command.kind == EMPTY:
                    delivery._finish("sent")  # the firmware ignores it (main.c 452): no ack to wait for
                else:
                    delivery.status = "sent"
                    delivery._deadline = written + self.ack_timeout
                    self._waiting = delivery
        self._read(port, start + self._reply_timeout, reply=True)
        self._read(port, start + self._period, reply=False)

    def _next_command(self, now: float) -> Delivery | None:
        """The command this poll carries (called under the lock): the one waiting for its ack again if its
        ack timeout has passed, else nothing while it waits, else the next queued one. Gives up on a
        command sent :attr:`attempts` times."""
        w = self._waiting
        if w is not None:
            if now < w._deadline:
                return None
            if w.attempts < self.attempts:
                log.info("no ack for %r after %.3g s: sending it again", w.command, self.ack_timeout)
                return w
            self._waiting = None
            self._unacknowledged += 1
            self._command_error = (
                f"command {chr(w.command.code)!r} to {_addressee(w.command)} got no acknowledgement "
                f"after {w.attempts} attempts, {self.ack_timeout:g} s apart"
            )
            log.warning("%s", self._command_error)
            w._finish("failed", error=self._command_error)
        return self._commands.popleft() if self._commands else None

    def _run(self) -> None:
        delay = self._backoff[0]
        while not self._stop.is_set():
            port = self._port
            if port is None:
                if self._try_open():
                    delay = self._backoff[0]
                else:
                    self._stop.wait(delay)
                    delay = min(2.0 * delay, self._backoff[1])
                continue
            try:
                self._cycle(port)
            except (serial.SerialException, OSError, TypeError, AttributeError) as e:
                # pyserial raises TypeError/AttributeError when a port is closed under a pending read.
                self._lost(e)
        port, self._port = self._port, None
        if port is not None:
            port.close()

    # ------------------------------------------------------------------ the API

    @property
    def connected(self) -> bool:
        """Whether the port is open."""
        return self._port is not None

    def send(self, command: Command) -> Delivery:
        """Queue a downlink command: it goes out in the command slot of a coming poll once every command
        queued before it is done, and is sent again while no acknowledgement comes (up to
        :attr:`attempts` times, :attr:`ack_timeout` apart). Returns its :class:`Delivery`, which tells
        whether it was acknowledged; the acknowledgement also shows in ``ComponentState.acks``."""
        if not isinstance(command, Command):
            raise ProtocolError(f"send takes a Command, got {type(command).__name__}")
        command.encode()  # refuse a command that cannot be sent now, not on the thread
        delivery = Delivery(command)
        with self._cond:
            if self._stop.is_set():
                delivery._finish("failed", error=f"the reader of {self.url} is closed")
            else:
                self._commands.append(delivery)
        return delivery

    @property
    def pending(self) -> int:
        """Commands queued or waiting for their acknowledgement."""
        with self._cond:
            return len(self._commands) + (self._waiting is not None)

    def _snapshot(self) -> DeviceState:
        s = self._stats
        link = LinkStats(
            bytes=s.bytes,
            frames=s.records,
            empty=s.empty,
            corrupt=s.corrupt,
            skipped=s.skipped,
            short=s.short,
            oversize=s.oversize,
            missing=s.missing,
            polls=s.polls,
            echoes=s.echoes,
            commands=self._sent,
            resent=self._resent,
            unacknowledged=self._unacknowledged,
            command_error=self._command_error,
            reconnects=self._reconnects,
            error=self._error,
        )
        return self._topology.snapshot(self._clock(), connected=self._port is not None, link=link)

    def state(self) -> DeviceState:
        """The latest consistent device state (an immutable snapshot; cheap enough for every frame)."""
        with self._cond:
            return self._snapshot()

    def wait_for(self, predicate: Callable[[DeviceState], bool], timeout: float) -> DeviceState | None:
        """Block until ``predicate(state)`` holds (checked on every update and at least every 20 ms) and
        return that state, or None after ``timeout`` seconds."""
        deadline = self._clock() + timeout
        with self._cond:
            while True:
                state = self._snapshot()
                if predicate(state):
                    return state
                left = deadline - self._clock()
                if left <= 0:
                    return None
                self._cond.wait(min(left, 0.02))

    def close(self) -> None:
        """Stop the thread and close the port (idempotent)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()
        port, self._port = self._port, None
        if port is not None:
            port.close()
        with self._cond:
            left = ([self._waiting] if self._waiting is not None else []) + list(self._commands)
            self._waiting = None
            self._commands.clear()
        for d in left:
            d._finish(
                "failed", error=f"the reader of {self.url} was closed before {d.command!r} was acknowledged"
            )

    def __enter__(self) -> SerialReader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _addressee(command: Command) -> str:
    """Whom a command is for, in words."""
    if command.target is None:
        return "the piece on the host"
    return "every piece" if command.target == BROADCAST_ID else f"piece {command.target:#x}"
