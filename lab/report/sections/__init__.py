"""Sections of the reproduction report, one per experiment of the paper.

Each function runs its experiment on the simulated cell (virtual time, fixed seeds),
draws its figures into ``out`` and returns a Section: Markdown, numbers, and rows of the
paper-versus-ours table. Sections are independent, so they can run in parallel.
"""

from .distance import distance_flow_control, distance_pressure_flow, distance_tank
from .objects import gripper, profile_scan, shape, stiffness
from .suction import resolution, retrofit, suction
from .tasks import tasks
from .timing import timing

SECTIONS = [distance_tank, distance_pressure_flow, distance_flow_control, gripper, shape, stiffness, profile_scan,
            suction, retrofit, resolution, timing, tasks]
