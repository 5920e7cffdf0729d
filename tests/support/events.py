"""The published events' schemas (docs/zmq-schema.md) and a fast profile for daemons that publish."""

from __future__ import annotations

import json
import re

import jsonschema

from support.harness import PROFILE, REPO

DOC = (REPO / "docs" / "zmq-schema.md").read_text()
SCHEMAS = {m.group(1): json.loads(m.group(2))
           for m in re.finditer(r"```json schema=(\w+)\n(.*?)```", DOC, flags=re.S)}


def check(topic: str, msg: dict) -> None:
    assert topic in SCHEMAS, f"topic {topic!r} is not documented"
    jsonschema.validate(msg, SCHEMAS[topic])


def fast_profile(tmp_path):
    """The gripper with a 3.5 s cycle so that real-time tests stay short."""
    from support.configs import profile_config

    return str(profile_config(tmp_path, PROFILE, sequence={
        "charge_s": 0.5, "isolate_s": 0.5, "actuate_s": 2.0, "vent_s": 0.5, "offset_s": 0.3,
        "windows": [{"name": "eq", "start_s": 1.0, "end_s": 1.5}]}))
