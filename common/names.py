"""Names the command line and the clients offer, in a module with no imports: the CLI's
parsers are built from them without loading pydantic, numpy or scipy, and the client
library speaks them without the controller.

Where a list here is also defined by a model (the requests, by the models that
controller/requests answers), the model is the source and this is its light copy:
tests/unit/test_requests.py checks that the two agree.
"""

from __future__ import annotations

FIT_DEGREE = {"linear": 1, "poly2": 2, "poly3": 3}

# feature name -> (CycleResult attribute, unit at the edge, scale from SI to that unit)
FEATURES: dict[str, tuple[str, str, float]] = {
    "p_eq": ("p_eq", "kPa", 1e-3),
    "v_eq": ("v_eq", "ml", 1e6),
    "dp_eq": ("dp_eq", "kPa", 1e-3),
    "dp_max": ("dp_max", "kPa", 1e-3),
    "t_c_slope": ("t_c_slope", "s", 1.0),
    "t_c_threshold": ("t_c_threshold", "s", 1.0),
    "t_c2": ("t_c2", "s", 1.0),
    "t_c_onset": ("t_c_onset", "s", 1.0),
}
NEEDS_REFERENCE = {"dp_eq", "dp_max", "t_c_slope", "t_c_threshold", "t_c2", "t_c_onset"}

#: the command socket's requests, as the daemon lists them (the light copy of the names
#: of the models in controller/requests)
COMMANDS = ("status", "cycle", "abort", "reset", "scene", "task", "shutdown", "grip", "release", "measure")

#: the published topics (docs/zmq-schema.md has a schema for each); the gripper's are the
#: events of a grip, which the client library types
GRIPPER_TOPICS = ("contact", "grasp", "slip", "released")
TOPICS = ("pressure", "state", "cycle", "heartbeat", "fault", "task", "log", *GRIPPER_TOPICS)
#: the one-frame message a subscriber gets when its subscription is attached: ``hello``, a
#: space and the id of the daemon instance that sent it (``welcome_frame``). Subscribe to
#: ``hello`` (a prefix) to get it.
WELCOME = b"hello"
#: the id's length (hex digits): random per daemon start, so a restart on the same ports is told
INSTANCE_HEX = 16


def welcome_frame(instance: str) -> bytes:
    return WELCOME + b" " + instance.encode("ascii")


def welcome_instance(frames: list[bytes]) -> str | None:
    """The instance id of a welcome message, ``""`` for a welcome without one (a daemon
    before schema version 2), None for anything that is not a welcome."""
    if len(frames) != 1:
        return None
    frame = frames[0]
    if frame == WELCOME:
        return ""
    if frame.startswith(WELCOME + b" "):
        return frame[len(WELCOME) + 1:].decode("ascii", "replace")
    return None
