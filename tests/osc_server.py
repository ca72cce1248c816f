"""python-osc's own server on a thread, for the tests of what BodyCal sends over VMC (an OSC
implementation the project did not write checks the addresses, types and values)."""

import threading

from pythonosc.dispatcher import Dispatcher
from pythonosc.osc_server import BlockingOSCUDPServer


class OscServer:
    """python-osc's blocking server on a thread, keeping (address, args) in arrival order."""

    def __init__(self):
        self.messages = []
        d = Dispatcher()
        d.set_default_handler(lambda address, *args: self.messages.append((address, list(args))))
        self.server = BlockingOSCUDPServer(("127.0.0.1", 0), d)
        self.port = self.server.server_address[1]
        self.thread = threading.Thread(target=self.server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.server.shutdown()
        self.server.server_close()
        self.thread.join(5)

    def wait_for(self, count_address, n, seconds=3.0):
        deadline = threading.Event()
        timer = threading.Timer(seconds, deadline.set)
        timer.start()
        try:
            while sum(a == count_address for a, _ in self.messages) < n:
                assert not deadline.wait(0.01), "timed out"
        finally:
            timer.cancel()
