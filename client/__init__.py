"""A client of the fluidsense daemon: drive it as a gripper and follow its events.

    from fluidsense.client import Gripper

    with Gripper("tcp://127.0.0.1:5561", "tcp://127.0.0.1:5560") as g:
        g.measure(store_reference=True)     # nothing in the gripper: the free-air reference
        grasp = g.grip()                    # waits for the grasp (contact first, if any)
        print(grasp.object, grasp.size)     # True, Estimate(quantity='diameter', value_mm=60.2, ...)
        g.release()

``AsyncGripper`` is the same for asyncio: both run the calls of one core (core.py).
Requests go over a REQ socket that is made again after a timeout (a REQ socket that missed
its reply is stuck); events come over a SUB socket attached before the first request, so
no event of a request is missed. A wait takes events only from the daemon instance that
answered its request: a restart on the same endpoints ends it with ``DaemonRestarted``. CURVE keys are optional (``curve=(client secret key
file, server public key file)``). The messages and their fields: docs/zmq-schema.md.
"""

from fluidsense.common.names import GRIPPER_TOPICS

from .aio import AsyncGripper
from .sync import Gripper
from .types import (
           Contact,
           DaemonRestarted,
           Estimate,
           Event,
           Grasp,
           GripEnded,
           NoReply,
           NoWelcome,
           Refused,
           Released,
           Slip,
           typed,
)

__all__ = ["AsyncGripper", "Contact", "DaemonRestarted", "Estimate", "Event", "GRIPPER_TOPICS", "Grasp", "GripEnded",
           "Gripper", "NoReply", "NoWelcome", "Refused", "Released", "Slip", "typed"]
