"""Bad limits, names and mounts raise ConfigError naming the field and the value."""

from __future__ import annotations

import dataclasses
import math

import pytest

from secure3d.dynamics import (
    CameraMount,
    DiffDriveLimits,
    PointMassLimits,
    QuadrotorLimits,
    make_model,
    model_from_spec,
)
from secure3d.errors import ConfigError
from secure3d.world.spec import CameraSpec, VehicleSpec

LIMITS = {
    "point_mass": PointMassLimits,
    "quadrotor": QuadrotorLimits,
    "diff_drive": DiffDriveLimits,
}
FLOAT_FIELDS = [
    (name, f.name)
    for name, cls in LIMITS.items()
    for f in dataclasses.fields(cls)
    if f.name not in ("accel_norm",)
]


@pytest.mark.parametrize(("model", "field"), FLOAT_FIELDS)
@pytest.mark.parametrize("bad", [-1.0, float("nan"), float("inf"), "fast", True])
def test_bad_limit_values_name_the_field(model, field, bad):
    with pytest.raises(ConfigError, match=field) as info:
        make_model(model, **{field: bad})
    assert repr(bad) in str(info.value) or str(bad) in str(info.value)


@pytest.mark.parametrize(("model", "field"), FLOAT_FIELDS)
def test_zero_limits_rejected_except_where_meaningful(model, field):
    allowed = {("quadrotor", "thrust_min"), ("diff_drive", "height")}
    if (model, field) in allowed:
        make_model(model, **{field: 0.0})
    else:
        with pytest.raises(ConfigError, match=field):
            make_model(model, **{field: 0.0})


def test_quadrotor_that_cannot_hover():
    with pytest.raises(ConfigError, match="thrust_max.*cannot hover"):
        make_model("quadrotor", thrust_max=9.0)
    with pytest.raises(ConfigError, match="thrust_max.*cannot hover"):
        make_model("quadrotor", thrust_max=3.0, gravity=3.0)
    with pytest.raises(ConfigError, match="thrust_min.*cannot hover"):
        make_model("quadrotor", thrust_min=10.0)
    with pytest.raises(ConfigError, match="max_tilt"):
        make_model("quadrotor", max_tilt=2.0)
    make_model("quadrotor", thrust_max=10.0)  # just above g: fine


def test_unknown_names_and_fields():
    with pytest.raises(ConfigError, match="vehicle.model.*'boat'"):
        make_model("boat")
    with pytest.raises(ConfigError, match=r"vehicle.limits.max_acel.*5"):
        make_model("point_mass", max_acel=5)
    with pytest.raises(ConfigError, match="accel_norm.*'sphere'"):
        make_model("point_mass", accel_norm="sphere")


@pytest.mark.parametrize("radius", [0.0, -0.1, float("nan"), 10.0])
def test_bad_body_radius(radius):
    with pytest.raises(ConfigError, match="body_radius"):
        make_model("point_mass", body_radius=radius)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"pitch": 2.0}, "pitch"),
        ({"pitch": float("nan")}, "pitch"),
        ({"pitch": "down"}, "pitch"),
        ({"offset": (0, 0)}, "offset"),
        ({"offset": (0, 0, float("inf"))}, "offset"),
    ],
)
def test_bad_mount(kwargs, field):
    with pytest.raises(ConfigError, match=field):
        CameraMount(**kwargs)


def test_model_from_spec_uses_vehicle_and_camera():
    vehicle = VehicleSpec(
        model="quadrotor", body_radius=0.3, limits={"max_speed": 3, "thrust_max": 15}
    )
    camera = CameraSpec(mount_pitch_deg=20.0, mount_offset=(0.1, 0.0, -0.05))
    model = model_from_spec(vehicle, camera)
    assert model.name == "quadrotor" and model.body_radius == 0.3
    assert model.limits.max_speed == 3.0 and model.limits.thrust_max == 15.0
    assert math.isclose(model.mount.pitch, math.radians(20.0))
    assert model.mount.offset == (0.1, 0.0, -0.05)
    with pytest.raises(ConfigError, match="thrust_max"):
        model_from_spec(VehicleSpec(model="quadrotor", limits={"thrust_max": 5}), camera)


def test_limits_are_frozen_and_normalised():
    lim = PointMassLimits(max_accel=3)
    assert isinstance(lim.max_accel, float)
    with pytest.raises(dataclasses.FrozenInstanceError):
        lim.max_accel = 5.0  # type: ignore[misc]
