"""The recording, in one package: the daemon writes what its controller sees to MCAP
files, and the replay driver plays them back (docs/recording.md).

- :mod:`.schema`: what a file holds (format name and version, topics, channel schemas);
- :mod:`.messages`: a block or an event as JSON, and a recorded block read back;
- :mod:`.writer`: ``RecordingWriter``, one MCAP file;
- :mod:`.chunks`: MCAP chunks from untrusted files, decompressed within bounds;
- :mod:`.reader`: ``RecordingReader``, a file in order, up to its last complete record;
- :mod:`.sink`: ``RecordingSink``, the daemon's files (rotation, flushes, fsync, disk
  space), fed by the controller's telemetry;
- :mod:`.config`: the ``recording:`` section and the replay driver's entry;
- :mod:`.backend`: the replay driver.

It sits with the drivers because a replay backend is a driver and drivers import nothing
above them; the sink needs no more than the format (the daemon hands it the config and
the controller's references). The controller's cycle analysis run again on a recording
(``fluidsense replay``) is controller/cycles/reanalysis.py: it is the controller's
analysis. Nothing here is imported until used: reading a cell config imports
:mod:`.config` only (pydantic, no mcap).
"""
