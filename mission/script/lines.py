"""Where in a mission's own script the running call came from: the line the dashboard's
lanes and a prediction's unknown reads name."""

from __future__ import annotations

import sys
from types import FrameType

from dronefleet.mission.lifecycle.mission import Mission


def script_line(mission: Mission) -> int | None:
    """The line of the mission's own script the running verb was called from (the
    innermost frame compiled from it); None when only a plugin's code is on the stack."""
    code = getattr(mission, "code", None)
    filename = getattr(code, "co_filename", None)
    # The verb's caller and outward. Not sys._getframe(2): a verb handed to `run` as a
    # subroutine (`run(land, d)`) starts a greenlet's stack with no frame above it,
    # and _getframe raised "call stack is not deep enough".
    frame: FrameType | None = sys._getframe(1).f_back
    while frame is not None:
        if frame.f_code.co_filename == filename:
            return frame.f_lineno
        frame = frame.f_back
    return None
