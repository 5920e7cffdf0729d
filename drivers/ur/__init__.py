"""The ur-rtde driver (``driver: {kind: ur}``): a UR control box through ur_rtde.

``config`` is pydantic only; ``backend`` (imported when a config selects this driver)
builds the devices; ``worker`` and ``poller`` run in their own processes, where ur_rtde
is imported.
"""
