"""What ``bench stability`` perturbs and how it scores: the tables the bench and its
report (stability_report.py) share."""

SEED = 1
SIZE_THRESHOLD_MM = 5.0  # half the 10 mm spacing a size decision must resolve
TASK_THRESHOLD = 0.8  # success rate (4 rounds of 5, 8 sorts of 10)
CAL_TARGETS = [40, 55, 70, 85, 100]

# name: (unit, strengths, description)
PERTURBATIONS = {
    "off-centre": ("mm", [0.0, 5.0, 10.0], "object this far off the gripper's centre"),
    "slow actuation": ("Pa*s/m^3", [1e8, 5.7e8, 2e9], "flow resistor before the gripper (nominal 1e8)"),
    "leak": ("Pa*s/m^3", [0.0, 1e12, 2e11], "gripper leak to atmosphere (0: none)"),
    "sensor drift": ("kPa/h", [0.0, 1.0, 5.0], "sensor offset drifting over the test"),
    "temperature": ("K", [0.0, 1.0, 3.0], "tank air warmer than the room by this much when the valve opens"),
    "noise": ("x", [1.0, 2.0, 4.0], "sensor noise, times the default 0.07 kPa"),
    "regulator error": ("kPa", [0.0, 0.5, 2.0], "regulator landing this far above its setpoint"),
    "soft object": ("N/mm", [0.0, 5.0, 1.0], "object stiffness (0: rigid)"),
}
SIZE_METHODS = {
    # method: (feature of the cycle result, needs a reference, fit)
    "p_eq": ("p_eq", False, "linear"),
    "dp_eq, stale reference": ("dp_eq_stale", True, "linear"),
    "dp_eq, fresh reference": ("dp_eq", True, "linear"),
    "p_eq, offset once": ("p_eq_offset_once", False, "linear"),
    "t_c first rise": ("t_c_onset", True, "poly2"),
    "t_c at dP threshold": ("t_c_threshold", True, "poly2"),
    "dp_max": ("dp_max", True, "linear"),
}
