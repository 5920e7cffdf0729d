"""The Modbus driver (``driver: {kind: modbus}``): valves, regulator and analog inputs
through Modbus TCP (pymodbus 3), by default on a UR control box's register map.

``config`` is pydantic only; ``backend`` builds the devices when a config selects this
driver; ``poller`` runs in the sampler process.
"""
