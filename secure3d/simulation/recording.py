"""What a flight records, and the recorder that records nothing.

A flight logs through a recorder it is given (:class:`~secure3d.viz.rerun_log.RerunRecorder` for a
``.rrd`` file); without a recording it is given :data:`NULL_RECORDER`, whose every method does
nothing, so that flight code calls the recorder unconditionally instead of checking for ``None``
at every call.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np


class Recorder(Protocol):
    """The calls a flight makes on its recording (see ``RerunRecorder`` for their arguments)."""

    #: False for the null recorder: callers skip *preparing* costly arguments (the server's claim,
    #: the belief's obstacle voxels) that nothing would record.
    recording: bool

    def log_world(self, **kwargs: Any) -> None: ...
    def log_camera(self, t: float, *args: Any) -> None: ...
    def log_belief(self, t: float, *args: Any) -> None: ...
    def log_plan(self, t: float, plan: Any, label: str | None = None) -> None: ...
    def log_state(self, t: float, *args: Any) -> None: ...
    def log_scalar(self, t: float, name: str, value: float) -> None: ...
    def log_event(self, t: float, text: str, level: str = "INFO") -> None: ...
    def abort(self) -> None: ...


class NullRecorder:
    """A recorder that records nothing: every ``log_*`` call (and ``abort``) is a no-op."""

    recording = False

    def log_world(self, **kwargs: Any) -> None:
        pass

    def log_camera(self, t: float, *args: Any) -> None:
        pass

    def log_belief(self, t: float, *args: Any) -> None:
        pass

    def log_plan(self, t: float, plan: Any, label: str | None = None) -> None:
        pass

    def log_state(self, t: float, *args: np.ndarray | float) -> None:
        pass

    def log_scalar(self, t: float, name: str, value: float) -> None:
        pass

    def log_event(self, t: float, text: str, level: str = "INFO") -> None:
        pass

    def abort(self) -> None:
        pass


#: The one null recorder (it holds no state).
NULL_RECORDER = NullRecorder()
