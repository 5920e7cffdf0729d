"""Configuration: pydantic models loaded from YAML (cell.py: a whole cell; profile.py: an
actuator profile), and the loading that treats every file as untrusted input."""

from .cell import (
                   CellConfig,
                   CurveKeys,
                   LiveConfig,
                   LoopConfig,
                   PublisherConfig,
                   RecordingConfig,
                   Supervision,
                   load_cell_config,
                   load_profile,
)
from .loading import load_model, read_yaml, validate
from .profile import (
                   CalibrationPlan,
                   FlowProfile,
                   Limits,
                   Profile,
                   SequenceConfig,
                   Window,
)

__all__ = ["CalibrationPlan", "CellConfig", "CurveKeys", "FlowProfile", "LiveConfig", "Limits", "LoopConfig", "Profile",
           "PublisherConfig", "RecordingConfig", "SequenceConfig", "Supervision", "Window", "load_cell_config",
           "load_model", "load_profile", "read_yaml", "validate"]
