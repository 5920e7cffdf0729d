"""The service: a cell config wired to a backend, a controller and its sockets
(``app.py``), and systemd's notify protocol (``notify.py``)."""
