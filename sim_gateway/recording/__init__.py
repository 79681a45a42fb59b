"""A Rerun recording of a run: the junction, every reservation, and what vehicles did.

:class:`SpaceTimeRecorder` (in :mod:`.recorder`) composes the parts; what the
recording shows and how to read it is in ``docs/recording.md``.
"""

from dica.sim_gateway.recording.recorder import (
    STATUS_STYLE,
    TOP_EVERY,
    SpaceTimeRecorder,
    Status,
    approach_of,
)

__all__ = ["STATUS_STYLE", "TOP_EVERY", "SpaceTimeRecorder", "Status", "approach_of"]
