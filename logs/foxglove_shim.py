"""A loopback proxy in front of foxglove-sdk's WebSocket server that also accepts ``foxglove.websocket.v1``.

foxglove-sdk (0.30) answers a WebSocket handshake only when the client offers ``foxglove.sdk.v1``;
older Foxglove and Lichtblick releases, PlotJuggler and the protocol's own specification offer
``foxglove.websocket.v1`` and get HTTP 400. The two names stand for the same protocol (Foxglove
renamed it when the SDK replaced ws-protocol; the messages did not change), and the SDK has no
option to accept the old name. So the SDK server listens on a free loopback port and this proxy
listens where the user asked: it reads each client's HTTP upgrade request, and when the client
offers ``foxglove.websocket.v1`` but not ``foxglove.sdk.v1`` it offers the new name to the SDK and
gives the old one back in the SDK's answer (``Sec-WebSocket-Accept`` depends on the key only, not
on the subprotocol). After the handshake it copies bytes both ways untouched.

It runs an asyncio loop on a daemon thread of the process that owns the server (the recorder's
writer process for the live view): never on the control loop's thread or process.
"""

from __future__ import annotations

import asyncio
import re
import threading

SDK_SUBPROTOCOL = "foxglove.sdk.v1"
LEGACY_SUBPROTOCOL = "foxglove.websocket.v1"
_MAX_HEAD_BYTES = 16384  # an HTTP upgrade request or answer is far smaller
_HEADER = re.compile(rb"(?im)^sec-websocket-protocol:[ \t]*(?P<value>[^\r\n]*)\r?$")
_COPY_BYTES = 65536


def offered_subprotocols(head: bytes) -> list[str]:
    """The subprotocols an HTTP upgrade request offers (every ``Sec-WebSocket-Protocol`` header, in order)."""
    return [
        p.strip()
        for m in _HEADER.finditer(head)
        for p in m["value"].decode("latin-1").split(",")
        if p.strip()
    ]


def rewrite_request(head: bytes) -> tuple[bytes, bool]:
    """The request the SDK accepts, and whether it was changed (the legacy name offered, the new one not)."""
    offered = offered_subprotocols(head)
    if LEGACY_SUBPROTOCOL not in offered or SDK_SUBPROTOCOL in offered:
        return head, False
    return _HEADER.sub(b"Sec-WebSocket-Protocol: " + SDK_SUBPROTOCOL.encode() + b"\r", head, count=1), True


def rewrite_response(head: bytes) -> bytes:
    """The SDK's answer with the legacy name the client asked for."""
    return _HEADER.sub(b"Sec-WebSocket-Protocol: " + LEGACY_SUBPROTOCOL.encode() + b"\r", head, count=1)


async def _read_head(reader: asyncio.StreamReader) -> bytes:
    """An HTTP head up to and including the blank line (IncompleteReadError or LimitOverrunError if none)."""
    return await reader.readuntil(b"\r\n\r\n")


async def _copy(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    try:
        while data := await reader.read(_COPY_BYTES):
            writer.write(data)
            await writer.drain()
    except (ConnectionError, asyncio.CancelledError):
        pass
    finally:
        writer.close()


class SubprotocolShim:
    """Listens on ``host:port`` and forwards every connection to the SDK server at ``127.0.0.1:sdk_port``."""

    def __init__(self, host: str, port: int, sdk_port: int) -> None:
        self.sdk_port = sdk_port
        self.loop = asyncio.new_event_loop()
        self.server = self.loop.run_until_complete(
            asyncio.start_server(self._serve, host, port, limit=_MAX_HEAD_BYTES)
        )
        self.port: int = self.server.sockets[0].getsockname()[1]
        self.thread = threading.Thread(
            target=self.loop.run_forever, name="foxglove-subprotocol-shim", daemon=True
        )
        self.thread.start()

    async def _serve(self, client_r: asyncio.StreamReader, client_w: asyncio.StreamWriter) -> None:
        try:
            request, legacy = rewrite_request(await _read_head(client_r))
            sdk_r, sdk_w = await asyncio.open_connection("127.0.0.1", self.sdk_port, limit=_MAX_HEAD_BYTES)
        except (asyncio.IncompleteReadError, asyncio.LimitOverrunError, ConnectionError, OSError):
            client_w.close()
            return
        try:
            sdk_w.write(request)
            await sdk_w.drain()
            answer = await _read_head(sdk_r)
        except (asyncio.IncompleteReadError, asyncio.LimitOverrunError, ConnectionError, OSError):
            client_w.close()
            sdk_w.close()
            return
        try:
            client_w.write(rewrite_response(answer) if legacy else answer)
            await client_w.drain()
            await asyncio.gather(_copy(client_r, sdk_w), _copy(sdk_r, client_w))
        except (ConnectionError, asyncio.CancelledError):  # the client went, or the shim closes
            client_w.close()
            sdk_w.close()

    def close(self) -> None:
        async def shut() -> None:
            self.server.close()
            connections = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
            for task in connections:
                task.cancel()
            await asyncio.gather(*connections, return_exceptions=True)

        asyncio.run_coroutine_threadsafe(shut(), self.loop).result(timeout=5.0)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(5.0)
        self.loop.close()
