"""A Rerun recording of a run: the junction, every reservation, and what vehicles did.

:class:`SpaceTimeRecorder` composes the parts; what the recording shows and
how to read it is in ``docs/recording.md``.
"""

from dica.sim_gateway.recording.geometry import approach_of
from dica.sim_gateway.recording.recorder import SpaceTimeRecorder
from dica.sim_gateway.recording.style import STATUS_STYLE, Status
from dica.sim_gateway.recording.top_view import TOP_EVERY

__all__ = ["STATUS_STYLE", "TOP_EVERY", "SpaceTimeRecorder", "Status", "approach_of"]
