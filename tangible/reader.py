"""A background reader of the device over pyserial.

::

    with SerialReader("/dev/ttyACM0") as reader:        # or "loop://", "socket://host:port", a pty path
        state = reader.state()                          # immutable DeviceState, safe from any thread
        angles = state.joint_angles(state.attached)     # (k, 4)

The reader thread opens the port with ``serial.serial_for_url``, feeds every chunk it reads to a
:class:`~tangible.protocol.Decoder`, and applies the messages to a
:class:`~tangible.topology.DeviceTopology` under a lock, stamping them with the clock time the chunk
arrived. Bytes the operating system buffered before the port was opened are read like any others (newer
frames supersede them within a data period). If the port fails (unplugged, the pty's other end closed)
it closes it, marks the state disconnected, and reopens it with exponential backoff; components keep
their last data and go detached by the usual timeout. Nothing is printed; port trouble is logged to the
``tangible.reader`` logger and shown in ``state().link.error``.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable

import serial
from serial.tools import list_ports as _list_ports

from .errors import DeviceError
from .protocol import Decoder, Message
from .topology import DETACH_TIMEOUT, DeviceState, DeviceTopology, LinkStats

__all__ = ["SerialReader", "list_ports"]

log = logging.getLogger(__name__)

#: Baud rate asked of real UARTs (USB CDC and ptys ignore it); see PROTOCOL.md.
BAUDRATE = 1_000_000


def list_ports() -> list[tuple[str, str]]:
    """Serial ports on this machine as ``(device, description)`` pairs, USB ones first — what a port
    menu offers (a :class:`~tangible.simulator.Simulator`'s ``path`` can be offered beside them)."""
    ports = sorted(_list_ports.comports(), key=lambda p: (p.vid is None, p.device))
    return [(p.device, p.description if p.description != "n/a" else p.device) for p in ports]


class SerialReader:
    """Read a device on a serial port in a background thread and publish its latest state.

    Parameters
    ----------
    url : str
        Port name or pyserial URL (``"/dev/ttyUSB0"``, ``"COM3"``, ``"loop://"``, ``"socket://h:p"``).
    timeout : float
        Seconds of silence after which a component and its subtree are detached (2 s, Appendix A).
    read_timeout : float
        Longest a single blocking read waits; bounds how quickly :meth:`close` returns.
    backoff : (float, float)
        First and longest wait between attempts to reopen a failed port (doubling in between).
    open_port : callable, optional
        ``open_port(url) -> serial.SerialBase``; by default ``serial.serial_for_url`` with
        :data:`BAUDRATE` and ``read_timeout``. Lets a test share one ``loop://`` port with a writer.
    observer : callable, optional
        ``observer(message, time)`` is called on the reader thread for every message, right after it was
        published, with the clock time of publication. For instrumentation and recording; it must be
        quick and must not call back into the reader. Its exceptions are logged, not raised.
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
        read_timeout: float = 0.02,
        backoff: tuple[float, float] = (0.05, 1.0),
        open_port: Callable[[str], serial.SerialBase] | None = None,
        observer: Callable[[Message, float], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
        start: bool = True,
    ):
        self.url = url
        self._read_timeout = float(read_timeout)
        self._backoff = (float(backoff[0]), float(backoff[1]))
        self._open = open_port or self._default_open
        self._observer = observer
        self._clock = clock
        self._decoder = Decoder()
        self._topology = DeviceTopology(timeout)
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._port: serial.SerialBase | None = None
        self._reconnects = 0
        self._failed = False
        self._error = ""
        self._stats = self._decoder.stats.copy()
        self._thread = threading.Thread(target=self._run, name="tangible-reader", daemon=True)
        try:
            self._try_open()
        except ValueError as e:
            raise DeviceError(f"cannot use serial port {url!r}: {e}") from None
        if start:
            self.start()

    def _default_open(self, url: str) -> serial.SerialBase:
        return serial.serial_for_url(url, baudrate=BAUDRATE, timeout=self._read_timeout)

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
        with self._cond:
            port, self._port = self._port, None
            self._failed = True
            self._error = str(error)
            self._cond.notify_all()
        with contextlib.suppress(serial.SerialException, OSError):
            port.close()
        self._decoder.reset()

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
                data = port.read(port.in_waiting or 1)
            except (serial.SerialException, OSError, TypeError, AttributeError) as e:
                # pyserial raises TypeError/AttributeError when a port is closed under a pending read.
                self._lost(e)
                continue
            if not data:
                continue
            now = self._clock()
            messages = self._decoder.feed(data)
            with self._cond:
                for m in messages:
                    self._topology.observe(m, now)
                self._stats = self._decoder.stats.copy()
                self._cond.notify_all()
            if self._observer is not None and messages:
                published = self._clock()
                for m in messages:
                    try:
                        self._observer(m, published)
                    except Exception:
                        log.exception("observer failed on %r", m)
        port, self._port = self._port, None
        if port is not None:
            port.close()

    # ------------------------------------------------------------------ the API

    @property
    def connected(self) -> bool:
        """Whether the port is open."""
        return self._port is not None

    def _snapshot(self) -> DeviceState:
        s = self._stats
        link = LinkStats(
            s.bytes, s.frames, s.corrupt, s.oversize, s.unsupported, self._reconnects, self._error
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
