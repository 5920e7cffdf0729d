"""The NI-DAQmx driver (``driver: {kind: nidaqmx}``): hardware-timed continuous analog
input through NI's ``nidaqmx`` package, digital outputs for the valves, an analog output
for the regulator (docs/drivers.md). The package is named daqmx so that it never shadows
NI's ``nidaqmx``."""
