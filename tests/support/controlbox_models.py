"""Model factories for ``python -m fluidsense.simulator.controlbox --model tests.support.controlbox_models:NAME``:
what a plant-backed subclass of KinematicModel does, in miniature."""

from __future__ import annotations

from fluidsense.simulator.controlbox import AnalogDomain, KinematicModel


class LoopbackModel(KinematicModel):
    """Standard outputs wired back to the standard inputs, and each analog output to the
    analog input of the same number (the input reads the output's voltage)."""

    def __init__(self):
        super().__init__(analog_input_source=self._read_back)
        self.changes = 0

    def on_outputs_changed(self, t: float) -> None:
        self.changes += 1
        self.set_digital_inputs(0xFF, self.digital_outputs & 0xFF)

    def _read_back(self, channel: int, domain: AnalogDomain, t: float) -> float:
        out = self.analog_output(channel)
        return out.value if out.domain == domain else 0.0


def loopback() -> LoopbackModel:
    return LoopbackModel()


def not_a_model() -> object:
    return object()


#: the ramp's slope on analog input 0 (V/s); it wraps at 10 V, every 2 s
RAMP_V_PER_S = 5.0


def ramp() -> KinematicModel:
    """Analog input 0 reads a voltage ramp of the model's own time, so a value read through
    the box tells when the box sampled it: 5 V/s, modulo 10 V (0-10 V is the raw range)."""
    return KinematicModel(analog_input_source=lambda ch, domain, t: (RAMP_V_PER_S * t) % 10.0 if ch == 0 else 0.0)
