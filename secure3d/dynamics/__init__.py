"""Vehicle models: one definition serving CasADi (the NLP) and numpy (simulation).

- :class:`PointMass` (3D position, velocity, yaw; acceleration and yaw-rate control),
- :class:`Quadrotor` (position, velocity, quaternion; collective thrust and body rates),
- :class:`DiffDrive` (the paper's planar bounded-acceleration differential drive).

Build one with :func:`make_model` or from a scenario with :func:`model_from_spec`.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any

from secure3d.dynamics.base import CameraMount, VehicleModel
from secure3d.dynamics.diff_drive import DiffDrive, DiffDriveLimits
from secure3d.dynamics.integrate import rk4_step, rollout
from secure3d.dynamics.point_mass import PointMass, PointMassLimits
from secure3d.dynamics.quadrotor import Quadrotor, QuadrotorLimits
from secure3d.errors import ConfigError

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.world.spec import CameraSpec, VehicleSpec

#: The vehicle registry: model name -> class. Adding a vehicle is its module and one entry here.
MODELS: dict[str, type[VehicleModel]] = {
    PointMass.name: PointMass,
    Quadrotor.name: Quadrotor,
    DiffDrive.name: DiffDrive,
}
#: The vehicle a scenario flies unless it names one (``vehicle.model``).
DEFAULT_MODEL = PointMass.name

__all__ = [
    "DEFAULT_MODEL",
    "MODELS",
    "CameraMount",
    "DiffDrive",
    "DiffDriveLimits",
    "PointMass",
    "PointMassLimits",
    "Quadrotor",
    "QuadrotorLimits",
    "VehicleModel",
    "make_model",
    "model_from_spec",
    "rk4_step",
    "rollout",
]


def make_model(
    name: str, body_radius: float = 0.2, mount: CameraMount | None = None, **limits: Any
) -> VehicleModel:
    """Build a vehicle model by name.

    Parameters
    ----------
    name : a key of :data:`MODELS` (``"point_mass"``, ``"quadrotor"`` or ``"diff_drive"``).
    body_radius : radius of the ball bounding the body (m).
    mount : camera mount (default: level camera at the body centre).
    **limits : fields of the model's limits dataclass (e.g. ``max_accel=3.0``); missing fields keep
        their defaults.

    Raises
    ------
    ConfigError
        Unknown model name or limits field, or an invalid value (the message names the field).
    """
    try:
        cls = MODELS[name]
    except (KeyError, TypeError):
        raise ConfigError(f"vehicle.model: must be one of {tuple(MODELS)}, got {name!r}") from None
    known = {f.name for f in dataclasses.fields(cls.limits_type)}
    unknown = sorted(set(limits) - known)
    if unknown:
        raise ConfigError(
            f"vehicle.limits.{unknown[0]}: unknown field for {name} "
            f"(value {limits[unknown[0]]!r}); "
            f"known fields: {sorted(known)}"
        )
    return cls(cls.limits_type(**limits), body_radius=body_radius, mount=mount)


def model_from_spec(vehicle: VehicleSpec, camera: CameraSpec) -> VehicleModel:
    """The model a scenario describes: ``vehicle.model``, ``vehicle.limits`` and the camera mount.

    The mount pitch is ``radians(camera.mount_pitch_deg)`` and its offset ``camera.mount_offset``.
    """
    mount = CameraMount(
        pitch=math.radians(camera.mount_pitch_deg), offset=tuple(camera.mount_offset)
    )
    return make_model(
        vehicle.model, body_radius=vehicle.body_radius, mount=mount, **dict(vehicle.limits)
    )
