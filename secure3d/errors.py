"""Every error secure3d raises on purpose.

User input is checked with ``raise``, never ``assert``. Each class also derives from the builtin a
caller would naturally catch (``ValueError`` for bad values, ``OSError`` for unreadable files), so
``except ValueError`` keeps working for code that does not know secure3d.
"""

from __future__ import annotations


class Secure3DError(Exception):
    """Base class of all errors raised deliberately by secure3d."""


class ConfigError(Secure3DError, ValueError):
    """A configuration value (vehicle limits, camera, planner option) is invalid.

    The message names the field and the offending value.
    """


class ScenarioError(Secure3DError, ValueError):
    """A scenario file or object is invalid. The message names the file, the field and the value."""


class MapFormatError(Secure3DError, ValueError):
    """An OctoMap ``.bt``/``.ot`` file (or in-memory buffer) is malformed, truncated or hostile."""


class GeometryError(Secure3DError, ValueError):
    """A geometric input has the wrong shape, is not finite, or is degenerate."""


class PlanningError(Secure3DError, RuntimeError):
    """The planner was called in a way it cannot honour (not raised for solver failures:
    those are reported as a status in ``PlanResult``)."""


class SimulationError(Secure3DError, RuntimeError):
    """The closed-loop simulation cannot start or continue (e.g. broken world meshes)."""


class OutputError(Secure3DError, OSError):
    """An output path cannot be written: a directory, a wrong extension, or no write access.

    Raised before any work is done (:func:`secure3d.outputs.check_output_path`).
    """
