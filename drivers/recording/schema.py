"""What a recording holds: the format's name and version (its ``fluidsense`` metadata
record), its topics, and the JSON schema of every channel (MCAP channels carry them, so
any MCAP tool can read a recording without fluidsense). Files on disk depend on these
names: change them only with ``FORMAT_VERSION``.

The topics, in file order: ``/config`` (the first message), ``/reference`` (the free-air
references held when the file was opened), then ``/samples`` (every block, SI units) and
every controller event (``/state``, ``/cycle``, ``/fault``, ``/heartbeat``, ``/task``,
``/cycle_start``, ``/command``), whose payloads are those of the published interface
plus ``t_s``."""

from __future__ import annotations

from typing import Any

FORMAT = "fluidsense-recording"
FORMAT_VERSION = 1
METADATA_NAME = "fluidsense"

SAMPLES, CONFIG, REFERENCE = "samples", "config", "reference"  # topics of the recording itself

_NUMBERS = {"type": "array", "items": {"type": ["number", "null"]}}
SCHEMAS: dict[str, dict[str, Any]] = {
    SAMPLES: {
        "title": "fluidsense.SampleBlock",
        "description": "One block of samples as the driver delivered it. values[j][i] is channel j at "
                       "times_s[i], SI units: Pa gauge for pressures, standard m^3/s for flows; null where "
                       "the reading was not a finite number.",
        "type": "object", "required": ["seq", "times_s", "channels", "values", "missed", "late"],
        "properties": {
            "seq": {"type": "integer"}, "times_s": _NUMBERS,
            "channels": {"type": "array", "items": {"type": "string"}},
            "values": {"type": "array", "items": _NUMBERS},
            "missed": {"type": "integer", "description": "sample slots the source could not fill before this block"},
            "late": {"type": "integer", "description": "samples taken after their slot deadline"},
        },
    },
    REFERENCE: {
        "title": "fluidsense.Reference",
        "description": "A free-air reference the controller held when this file was opened: offset-corrected "
                       "actuator pressure (Pa) against time since the valve opened (s).",
        "type": "object", "required": ["t_s", "key_kpa", "cycle_id", "t_rel_s", "p_pa"],
        "properties": {"t_s": {"type": "number"}, "key_kpa": {"type": "number"}, "cycle_id": {"type": "integer"},
                       "t_rel_s": _NUMBERS, "p_pa": _NUMBERS},
    },
    "cycle_start": {
        "title": "fluidsense.CycleStart",
        "description": "What a cycle was started with (exact SI values, for replay).",
        "type": "object", "required": ["t_s", "cycle_id", "p0_pa", "label", "store_reference", "hold"],
        "properties": {"t_s": {"type": "number"}, "cycle_id": {"type": "integer"}, "p0_pa": {"type": "number"},
                       "label": {"type": ["string", "null"]}, "store_reference": {"type": "boolean"},
                       "hold": {"type": "boolean"}},
    },
    "command": {
        "title": "fluidsense.Command",
        "description": "A command the sequencer sent to a device (valve, regulator setpoint in Pa, flow "
                       "profile in standard m^3/s at sample times).",
        "type": "object", "required": ["t_s", "kind"],
        "properties": {"t_s": {"type": "number"}, "kind": {"enum": ["valve", "setpoint", "flow_profile"]}},
    },
}


def event_schema(topic: str) -> dict[str, Any]:
    return SCHEMAS.get(topic) or {
        "title": f"fluidsense.{topic}",
        "description": f"The payload of the published '{topic}' topic (docs/zmq-schema.md, schema version 1) "
                       "with t_s, the sample time when it was emitted.",
        "type": "object", "required": ["t_s"], "properties": {"t_s": {"type": "number"}},
    }
