"""Every frame of a session once, with its direction: a tap between a bus and its users.

``FrameTap`` wraps an open python-can bus. Every frame sent through it and every frame received
from it goes to one sink, once: the node set-up's SDO and NMT frames (canopen's notifier thread
reads through the tap), the cyclic PDOs, SYNC and heartbeats, EMCY, boot-up, foreign frames.

Own transmissions that the bus hands back are recognised exactly and dropped, so that a frame
this process sent is seen once, as sent, and never a second time as received:

- ``udp_multicast`` as ``open_bus`` opens it (``drivers/local_multicast.py``) hands back none:
  a kernel socket filter drops them, and the tap sends its frames as they are (``channel`` None:
  the token below was 40 bytes more in each datagram, packed by the sender and unpacked by every
  receiver, for nothing). python-can's own bus cannot leave out its own datagrams
  (``receive_own_messages`` is not implemented) and IP multicast loopback delivers them to every
  socket of the group, the sender's own included; for that bus (a plug-in may open one) the tap
  keeps its second line: the bus packs every field of a ``Message`` with
  msgpack, ``channel`` included, and unpacks it unchanged on receipt
  (``can/interfaces/udp_multicast/utils.py``: ``pack_message``/``unpack_message``; only the
  timestamp is replaced). The tap writes a token unique to itself into ``channel`` of every frame
  it sends: a received frame carrying it is this tap's own, whatever its COB-ID and bytes. Two
  identical frames from two senders (a foreign SYNC) stay apart.
- ``virtual``: python-can hands the sender's copy back with ``is_rx = False``
  (``can/interfaces/virtual.py``; ``open_bus`` asks for own messages).
- ``socketcan``: ``CAN_RAW_RECV_OWN_MSGS`` is off (python-can's default), so the sending socket
  never receives its own frames. ``is_rx`` is not used there: python-can derives it from
  ``MSG_DONTROUTE``, which marks every frame sent on this host, the simulator's on a vcan too.

A received frame goes to the sink with the time it came, from its receive timestamp
(``drivers/pacing.py`` ``arrival_s``), not the time it was read: the cyclic exchange sleeps through
its answer window and reads the answers at its end.

The sink is called under a lock: canopen's notifier thread receives while the caller's thread
sends. On the cyclic path the tap costs one more Python call per frame; the sink call it makes
replaces the one the cyclic exchange used to make.
"""

from __future__ import annotations

import itertools
import os
import threading
import time
from collections.abc import Callable, Sequence

import can
from can.interfaces.udp_multicast import UdpMulticastBus
from can.interfaces.virtual import VirtualBus

from drivers.cyclic_exchange import FrameSink
from drivers.local_multicast import LocalUdpMulticastBus
from drivers.pacing import arrival_s

_TAP_SERIAL = itertools.count(1)


def own_frame_token() -> str:
    """A ``channel`` value no other tap, in this process or another, writes."""
    return f"cheope-tap:{os.getpid()}:{next(_TAP_SERIAL)}:{os.urandom(4).hex()}"


class FrameTap(can.BusABC):
    """``bus`` with every frame sent or received handed to ``sink`` once, own echoes dropped.

    The tap owns ``bus``: its ``shutdown`` shuts ``bus`` down too.
    """

    def __init__(
        self, bus: can.BusABC, sink: FrameSink | None = None, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.bus = bus
        self.sink = sink
        self.clock = clock
        self.token = own_frame_token()
        self.sent = 0  # frames sent through the tap
        self.received = 0  # frames received, own echoes not counted
        self.own_echoes = 0  # own frames the bus handed back, dropped
        self._lock = threading.Lock()
        self._stamps_channel = isinstance(bus, UdpMulticastBus) and not isinstance(bus, LocalUdpMulticastBus)
        self._own: Callable[[can.Message], bool] | None = None  # None: the bus hands back no own frame
        if self._stamps_channel:
            token = self.token
            self._own = lambda msg: msg.channel == token
        elif isinstance(bus, VirtualBus):
            self._own = lambda msg: not msg.is_rx
        super().__init__(channel=bus.channel_info)
        self.channel_info = bus.channel_info
        self._can_protocol = bus.protocol

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self._stamps_channel:
            msg.channel = self.token
        self.bus.send(msg, timeout)
        self.sent += 1
        if self.sink is not None:
            with self._lock:
                self.sink(True, self.clock(), msg)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """The next frame another node sent, within ``timeout`` [s] (None: wait for ever)."""
        deadline = None if timeout is None or timeout <= 0.0 else self.clock() + timeout
        while True:
            msg = self.bus.recv(timeout)
            if msg is None:
                return None
            if self._own is not None and self._own(msg):
                self.own_echoes += 1
                if deadline is not None:
                    timeout = max(0.0, deadline - self.clock())
                continue
            self.received += 1
            if self.sink is not None:
                # when it came, not when it was read: a reader may sleep through its window first
                arrived_s = arrival_s(msg.timestamp, self.clock(), time.time())
                with self._lock:
                    self.sink(False, arrived_s, msg)
            return msg

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return self.recv(timeout), True  # recv is overridden; kept for BusABC's contract

    def _send_periodic_internal(
        self,
        msgs: can.Message | Sequence[can.Message],
        period: float,
        duration: float | None = None,
        autostart: bool = True,
        modifier_callback: Callable[[can.Message], None] | None = None,
    ) -> can.broadcastmanager.CyclicSendTaskABC:
        """The bus's own periodic sending (SocketCAN: the kernel's broadcast manager), not python-can's
        Python thread through ``send``. Its frames do not pass the tap: the bus hands them back as
        received (another socket of this host sent them), and so they are recorded, as received."""
        return self.bus._send_periodic_internal(msgs, period, duration, autostart, modifier_callback)

    def fileno(self) -> int:
        return self.bus.fileno()

    def shutdown(self) -> None:
        super().shutdown()
        self.bus.shutdown()
