"""`fluidsense run` over real ZeroMQ sockets, checked against docs/zmq-schema.md.

The subscriber here is written against the document: the JSON schemas are read out of
docs/zmq-schema.md, not from the code.

(Its tests with real peers: tests/system/test_zmq.py.)
"""

from __future__ import annotations

from support.events import SCHEMAS


def test_the_document_has_a_schema_per_topic():
    assert set(SCHEMAS) == {"heartbeat", "state", "cycle", "pressure", "fault", "task", "log", "contact", "grasp",
                            "slip", "released"}
    assert all(schema.get("additionalProperties") is False for schema in SCHEMAS.values())
