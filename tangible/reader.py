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
``reply_timeout`` has passed, and the rest of the cycle for stray bytes. Everything read goes through a
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

from .errors import DeviceError, ProtocolError
from .protocol import BAUDRATE, CYCLE, Command, ParserStats, Record, ReplyParser, poll_bytes
from .topology import DETACH_TIMEOUT, DeviceState, DeviceTopology, LinkStats

__all__ = ["SerialReader", "list_ports"]

log = logging.getLogger(__name__)


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
        backoff: tuple[float, float] = (0.05, 1.0),
        open_port: Callable[[str], serial.SerialBase] | None = None,
        observer: Callable[[Record, float], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
        start: bool = True,
    ):
        if not (period > 0 and reply_timeout > 0 and read_timeout > 0):
            raise DeviceError(
                f"period, reply_timeout and read_timeout must be positive, got {period!r}, "
                f"{reply_timeout!r}, {read_timeout!r}"
            )
        self.url = url
        self._period = float(period)
        self._reply_timeout = float(reply_timeout)
        self._read_timeout = float(read_timeout)
        self._backoff = (float(backoff[0]), float(backoff[1]))
        self._open = open_port or self._default_open
        self._observer = observer
        self._clock = clock
        self._parser = ReplyParser()
        self._topology = DeviceTopology(timeout)
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._commands: deque[Command] = deque()
        self._sent = 0
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
            command = self._commands.popleft() if self._commands else None
        poll = poll_bytes(command)
        self._publish(self._parser.poll(poll), self._clock())
        port.write(poll)
        if command is not None:
            with self._cond:
                self._sent += 1
        self._read(port, start + self._reply_timeout, reply=True)
        self._read(port, start + self._period, reply=False)

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

    def send(self, command: Command) -> None:
        """Queue a downlink command: it goes out in the command slot of a coming poll, one per poll, in
        order. Whether it was executed shows as an acknowledgement (``ComponentState.acks``)."""
        if not isinstance(command, Command):
            raise ProtocolError(f"send takes a Command, got {type(command).__name__}")
        command.encode()  # refuse a command that cannot be sent now, not on the thread
        with self._cond:
            self._commands.append(command)

    @property
    def pending(self) -> int:
        """Commands queued and not yet sent."""
        with self._cond:
            return len(self._commands)

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

    def __enter__(self) -> SerialReader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
