"""docs/zmq-schema.md holds a schema for every topic the daemon publishes. (`fluidsense run`
over real ZeroMQ sockets, each message checked against those schemas:
tests/system/test_zmq.py.)"""

from __future__ import annotations

from support.events import SCHEMAS


def test_the_document_has_a_schema_per_topic():
    assert set(SCHEMAS) == {"heartbeat", "state", "cycle", "pressure", "fault", "task", "log", "contact", "grasp",
                            "slip", "released"}
    assert all(schema.get("additionalProperties") is False for schema in SCHEMAS.values())
