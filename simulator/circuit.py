"""The configured circuit as a gas network: nodes, links and valves of the simulated cell
(the valve, the hose, the tank, the actuator, and the internal paths faults use), and
which node the pressure sensor reads."""

from __future__ import annotations

from fluidsense.common.hardware import (
    ACTUATE,
    PORT_VOLUME_M3,
    SUPPLY,
    VENT,
    FlowControlledCircuit,
    Hardware,
    TankCircuit,
)
from fluidsense.common.units import KPA, MM, P_ATM

from .elements import DM3_PER_S_BAR, bore_wall_time_s, gap_wall_time_s, tank_wall_time_s
from .gas import ATMOSPHERE, REGULATOR, FlowSource, Network, Pipe, VolumeLaw

AIR = "_air"  # internal valve: the actuator open to the air (a suction cup that let go)
FAULT_LEAK = "_fault_leak"  # internal valves for fault injection: a leak, a supply stuck open
FAULT_SUPPLY = "_fault_supply"
FAULTS = ("over_pressure", "leak", "sensor_nan", "sensor_stuck", "sensor_range", "no_data", "link_lost",
          "protective_stop")
_AIR_RESISTANCE = 1e7


def _valve_path(c, a: int, b: int, valve: str, when_open: bool, name: str, downstream_resistor: bool) -> Pipe:
    """The actuation valve's path a -> b: ISO 6358 when the circuit names one (a resistor
    then has a link of its own), else laminar valve (+ resistor)."""
    if c.valve is not None:
        el = ("iso6358", c.valve.sonic_conductance_dm3_per_s_bar * DM3_PER_S_BAR, c.valve.critical_ratio)
        return Pipe(a, b, 0.0, valve, when_open, name, element=el)
    r = c.valve_resistance_pa_s_per_m3 + (c.resistor_pa_s_per_m3 if downstream_resistor else 0.0)
    return Pipe(a, b, r, valve, when_open, name)


# The pressures the correlations are evaluated at (absolute): mid-range of the paper's
# tank charges (50-74 kPa gauge) and of its grippers' readings (20-40 kPa gauge).
_P_TANK_CORRELATION = P_ATM + 60 * KPA
_P_ACT_CORRELATION = P_ATM + 35 * KPA


def wall_times(c) -> dict[str, float]:
    """Wall time constant (s) per volume of a ``wall`` circuit: configured, or from its
    correlation (simulator/elements.py)."""
    th = c.thermal
    out = {"actuator": th.actuator_wall_s or gap_wall_time_s(th.actuator_gap_mm * MM, _P_ACT_CORRELATION)}
    if not isinstance(c, FlowControlledCircuit):
        out["tank"] = th.tank_wall_s or tank_wall_time_s(c.tank_m3, _P_TANK_CORRELATION, th.wall_delta_t_k,
                                                         th.tank_aspect)
    if c.hose is not None:
        out["line"] = th.line_wall_s or bore_wall_time_s(c.hose.bore_mm * MM, _P_ACT_CORRELATION)
    return out


def network(hw: Hardware, law: VolumeLaw) -> tuple[Network, dict[str, bool]]:
    """Nodes, links and valves of the configured circuit (see drivers.hardware). With a
    hose, the valve feeds a ``line`` node (the hose's volume) that the hose joins to the
    actuator."""
    c = hw.circuit
    p_atm = c.p_atm
    downstream = c.resistor_position == "downstream"
    links: list[Pipe] = []
    sources: list[FlowSource] = []
    # node order as before the hose existed (tank, actuator), so isothermal runs integrate the same system
    names, laws = [], []
    if not isinstance(c, FlowControlledCircuit):
        names.append("tank")
        laws.append(VolumeLaw.constant(c.tank_m3, p_atm))
    names.append("actuator")
    laws.append(law)
    act = names.index("actuator")
    port = act  # the valve's actuator port
    if c.hose is not None:
        names.append("line")
        laws.append(VolumeLaw.constant(c.hose.volume_m3, p_atm))
        port = names.index("line")
        links.append(Pipe(port, act, 0.0, None, True, "hose", element=("hose", c.hose.bore_mm * MM, c.hose.length_m)))
    vent_from = port
    if c.valve is not None and c.resistor_pa_s_per_m3 > 0:
        # an ISO valve and a laminar resistor in series need the volume between them: the
        # valve's outlet and fittings (PORT_VOLUME_M3, assumed)
        names.append("valve_out")
        laws.append(VolumeLaw.constant(PORT_VOLUME_M3, p_atm))
        out = names.index("valve_out")
        links.append(Pipe(out, port, c.resistor_pa_s_per_m3, None, True, "resistor"))
        port, vent_from = out, (out if downstream else port)
    if isinstance(c, FlowControlledCircuit):
        sources.append(FlowSource(port, ACTUATE, True))
    else:
        tank = names.index("tank")
        supply_valve = SUPPLY if isinstance(c, TankCircuit) else None
        links.append(Pipe(REGULATOR, tank, c.supply_resistance_pa_s_per_m3, supply_valve, True, "supply"))
        links.append(_valve_path(c, tank, port, ACTUATE, True, "actuate", True))
    if isinstance(c, TankCircuit) and c.vent_valve:
        links.append(_valve_path(c, vent_from, ATMOSPHERE, VENT, True, "vent", downstream))
    else:
        links.append(_valve_path(c, vent_from, ATMOSPHERE, ACTUATE, False, "vent", downstream))
    if c.leak_resistance_pa_s_per_m3 is not None:
        links.append(Pipe(act, ATMOSPHERE, c.leak_resistance_pa_s_per_m3, None, True, "leak"))
    links.append(Pipe(act, ATMOSPHERE, _AIR_RESISTANCE, AIR, True, AIR))
    links.append(Pipe(act, ATMOSPHERE, 2e10, FAULT_LEAK, True, FAULT_LEAK))
    links.append(Pipe(REGULATOR, act, c.valve_resistance_pa_s_per_m3, FAULT_SUPPLY, True, FAULT_SUPPLY))
    valves = {**dict.fromkeys(c.safe_valves, False), AIR: False, FAULT_LEAK: False, FAULT_SUPPLY: False}
    response = getattr(hw.actuator, "response_s", 0.0)
    dampers = {act: hw.actuator.damping} if response > 0 else None
    thermal = None
    if c.thermal.model == "wall":
        thermal = {names.index(k): tau for k, tau in wall_times(c).items()}
    net = Network(names, laws, links, p_atm=p_atm, p_std=p_atm, flow_sources=sources, dampers=dampers,
                  thermal=thermal)
    return net, valves


def sensed_node(hw: Hardware, net: Network) -> int:
    """The node the actuator's pressure sensor reads: the hose's valve end or the actuator."""
    hose = hw.circuit.hose
    return net.index["line"] if hose is not None and hose.sensor_at == "valve" else net.index["actuator"]
