"""fluidsense: a closed-loop controller service for soft pneumatic grippers with retrofit
fluidic sensing (one pressure sensor on the tube, no sensor in the actuator).

The repository's root is this package (docs/architecture.md, "One namespace"): its
folders are its parts, from the command line down to the shared vocabulary::

    cli/         the ``fluidsense`` command line (``python -m fluidsense``)
    daemon/      the service wired: config -> backend -> controller -> sockets
    client/      the client library for other programs (ZeroMQ only)
    tasks/       sorting, picking, ripeness, calibration
    controller/  sample loop, supervisor, cycles, features, telemetry, requests
    drivers/     ur-rtde, Modbus, serial, NI-DAQmx, replay, the simulated cell's adapter
    simulator/   the simulated plant and the emulated UR control box
    common/      errors, units, models and names shared by all
    config/      shipped cell configs, profiles, tasks and calibrations (package data)

Importing this package loads nothing else.
"""

__version__ = "0.1.0"
