"""The live view's parts that need no daemon: the ``--live`` address and the WebSocket
subprotocol names read from a handshake. (A real daemon serving real WebSocket clients:
tests/system/test_live.py.)"""

from __future__ import annotations

import pytest
from fluidsense.controller.telemetry.live import parse_listen


def test_parse_listen():
    assert parse_listen("8765") == ("127.0.0.1", 8765)
    assert parse_listen("0.0.0.0:9000") == ("0.0.0.0", 9000)
    assert parse_listen("[::1]:9000") == ("::1", 9000)
    for bad in ("", "x", "host:", ":80", "70000", "h:0"):
        with pytest.raises(ValueError):
            parse_listen(bad)


def test_a_viewer_of_another_protocol_is_refused_and_both_names_are_read_from_the_handshake():
    from fluidsense.controller.telemetry.live_front import offered, rename_request, rename_response

    head = (b"GET / HTTP/1.1\r\nHost: x\r\nSec-WebSocket-Protocol: foxglove.websocket.v1\r\n"
            b"sec-websocket-protocol: other.v2\r\n\r\n")
    assert offered(head) == [b"foxglove.websocket.v1", b"other.v2"]
    renamed, legacy = rename_request(head)
    assert legacy and offered(renamed) == [b"foxglove.sdk.v1", b"other.v2"] and renamed.endswith(b"\r\n\r\n")
    both = b"GET / HTTP/1.1\r\nSec-WebSocket-Protocol: foxglove.websocket.v1, foxglove.sdk.v1\r\n\r\n"
    assert rename_request(both) == (both, False)  # the SDK's own name offered: left to the SDK
    assert rename_response(b"HTTP/1.1 101 x\r\nSec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n") == \
        b"HTTP/1.1 101 x\r\nSec-WebSocket-Protocol: foxglove.websocket.v1\r\n\r\n"
