"""The shipped cell configs, actuator profiles, task files and calibrations (package
data): installed as ``fluidsense/config/`` inside the wheel, read from ``config/`` in a
checkout. ``SHIPPED`` is that folder, wherever the package was installed."""

from pathlib import Path

SHIPPED = Path(__file__).resolve().parent
