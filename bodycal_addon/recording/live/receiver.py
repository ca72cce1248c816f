"""`VmcReceiver`: a VMC stream received on its own thread (DESIGN.md "Live source").

The thread blocks on the UDP socket (waking every POLL_S to see whether it should stop), turns
each datagram into frames as it arrives (vmc.FrameAssembler), gives every frame to the sinks (the
recorder) and puts it in the latest-wins slot for a consumer that runs at its own pace. It never
queues frames: Rokoko's Blender receiver reads one datagram per timer tick, so a sender faster than
the timer builds a backlog in the socket and a latency that grows; VMC4B's thread appends every
message to a queue that the timer drains. Here a consumer that falls behind gets the newest frame
and the count of those it missed (`stats.dropped`), and the socket is always read at the rate
datagrams arrive.

Bad datagrams and messages are counted and skipped (SourceStats); nothing a sender sends ends the
thread.
"""

from __future__ import annotations

import contextlib
import errno
import socket
import threading
import time
from collections.abc import Callable

from ...core.errors import BodyCalError
from .source import LatestSlot, LiveFrame, SourceStats
from .vmc import DEFAULT_PORT, FrameAssembler, now

POLL_S = 0.1  # how often the blocked thread looks whether it should stop
RECEIVE_BUFFER = 1 << 22  # bytes asked of the kernel for datagrams not yet read (it may give less)
MAX_DATAGRAM = 65535


class VmcReceiver:
    """A `LiveSource` (source.py) for the VMC protocol. `bind` is the address to listen on:
    127.0.0.1 (the default) hears senders on this machine only, 0.0.0.0 every network; port 0 picks
    a free port (`port` says which, once started)."""

    def __init__(self, port: int = DEFAULT_PORT, bind: str = "127.0.0.1"):
        self.requested = (bind, int(port))
        self.stats = SourceStats()
        self.assembler = FrameAssembler(self.stats)
        self._slot = LatestSlot()
        self._sinks: list[Callable[[LiveFrame], None]] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._sock: socket.socket | None = None
        self.port = int(port)

    # --- LiveSource -------------------------------------------------------------------------------

    def start(self) -> None:
        if self._thread is not None:
            return
        bind, port = self.requested
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER)
            sock.bind((bind, port))
        except OSError as exc:
            sock.close()
            why = (f"port {port} is in use (another VMC receiver, such as VSeeFace or VMC4B, or a second "
                   "bodycal?)" if exc.errno == errno.EADDRINUSE else f"cannot listen on {bind}:{port} "
                   f"({exc.strerror or exc})")
            raise BodyCalError(why, field="--port", hint="close the other receiver or pick another port") from None
        sock.settimeout(POLL_S)
        self._sock = sock
        self.port = sock.getsockname()[1]
        self._thread = threading.Thread(target=self._run, name=f"bodycal-vmc-{self.port}", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def latest(self) -> LiveFrame | None:
        return self._slot.take()

    def wait(self, timeout: float) -> bool:
        return self._slot.wait(timeout)

    def add_sink(self, sink: Callable[[LiveFrame], None]) -> None:
        self._sinks.append(sink)

    # --- more --------------------------------------------------------------------------------------

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def devices(self) -> dict[str, str]:
        """Device name -> kind, of every device the stream has named so far."""
        return dict(self.assembler.kinds)

    def __enter__(self) -> VmcReceiver:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def _run(self) -> None:
        cpu0 = time.thread_time()
        sock = self._sock
        while not self._stop.is_set():
            try:
                dgram = sock.recv(MAX_DATAGRAM)
            except TimeoutError:
                continue
            except OSError as exc:  # the socket closed under us: nothing more will come
                self.stats.last_error = f"socket: {exc.strerror or exc}"
                break
            for frame in self.assembler.feed(dgram, now()):
                self._deliver(frame)
            self.stats.cpu_seconds = time.thread_time() - cpu0
        with contextlib.suppress(OSError):  # what arrived before the stop was asked for is read too
            sock.setblocking(False)
            while True:
                for frame in self.assembler.feed(sock.recv(MAX_DATAGRAM), now()):
                    self._deliver(frame)
        last = self.assembler.flush(now())
        if last is not None:
            self._deliver(last)
        self.stats.cpu_seconds = time.thread_time() - cpu0

    def _deliver(self, frame: LiveFrame) -> None:
        for sink in list(self._sinks):
            try:
                sink(frame)
            except Exception as exc:  # noqa: BLE001 - the thread boundary: the sink's owner reads it
                self.stats.sink_error = f"{type(exc).__name__}: {exc}"
                self._sinks.remove(sink)
        self._slot.put(frame)
        self.stats.dropped = self._slot.dropped
