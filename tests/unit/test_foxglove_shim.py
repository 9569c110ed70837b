"""The live Foxglove server's subprotocol proxy (logs/foxglove_shim.py): what it changes in a handshake."""

from __future__ import annotations

from logs.foxglove_shim import offered_subprotocols, rewrite_request, rewrite_response

KEY = b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"


def _request(*protocol_lines: bytes) -> bytes:
    return (
        b"GET / HTTP/1.1\r\nHost: 127.0.0.1:8765\r\nUpgrade: websocket\r\n"
        + KEY
        + b"".join(protocol_lines)
        + b"\r\n"
    )


def test_a_legacy_only_offer_is_made_with_the_sdk_name_and_nothing_else_changes():
    request = _request(b"sec-websocket-protocol: foxglove.websocket.v1\r\n")
    rewritten, legacy = rewrite_request(request)
    assert legacy
    assert offered_subprotocols(rewritten) == ["foxglove.sdk.v1"]
    assert rewritten.replace(b"Sec-WebSocket-Protocol: foxglove.sdk.v1", b"") == request.replace(
        b"sec-websocket-protocol: foxglove.websocket.v1", b""
    )


def test_an_offer_with_the_sdk_name_or_without_foxglove_goes_through_untouched():
    for request in (
        _request(b"Sec-WebSocket-Protocol: foxglove.websocket.v1, foxglove.sdk.v1\r\n"),
        _request(
            b"Sec-WebSocket-Protocol: foxglove.websocket.v1\r\n",
            b"Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n",
        ),
        _request(b"Sec-WebSocket-Protocol: mqtt\r\n"),
        _request(),
    ):
        assert rewrite_request(request) == (request, False)


def test_the_answer_names_the_legacy_protocol_the_client_asked_for():
    answer = (
        b"HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\n"
        b"Sec-WebSocket-Accept: s3pPLMBiTxaQ9kYGzzhZRbK+xOo=\r\nSec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n"
    )
    assert offered_subprotocols(rewrite_response(answer)) == ["foxglove.websocket.v1"]
    assert b"Sec-WebSocket-Accept: s3pPLMBiTxaQ9kYGzzhZRbK+xOo=\r\n" in rewrite_response(answer)
