"""The thin-obstacle and 3D-occlusion scenario families, called directly (issue 16)."""

from __future__ import annotations

import numpy as np
import pytest

import secure3d
from secure3d.world.attacks import server_claim
from secure3d.world.families import variant_rng
from secure3d.world.spec import box_distance
from secure3d.world.thin_families import OCCLUSION_3D, THIN_OBSTACLES


def _rng(seed: int, i: int) -> np.random.Generator:
    return variant_rng(seed, i)


@pytest.mark.parametrize("family", [THIN_OBSTACLES, OCCLUSION_3D], ids=lambda f: f.name)
@pytest.mark.parametrize("base_name", ["blind_corner", "thin_pole", "beam_3d"])
def test_variants_hide_one_obstacle_across_the_route_and_are_pure(maps_dir, family, base_name):
    base = secure3d.load_scenario(maps_dir / f"{base_name}.yaml")
    prep = family.prepare(base)
    r = base.vehicle.body_radius
    kinds = set()
    for i in range(6):
        v = family.variant(prep, base, _rng(7, i), i)
        again = family.variant(prep, base, _rng(7, i), i)
        assert v.world.boxes == again.world.boxes and v.camera == again.camera
        assert len(v.world.boxes) == len(base.world.boxes) + 1
        box = v.world.boxes[-1]
        kinds.add(box.name.split("_")[1])
        # hidden from the server, present in the truth
        assert box.name in v.hidden_obstacles
        assert box.name not in {b.name for b in server_claim(v).boxes}
        # it cuts the body's path, and keeps the start and the goal clear
        lo, hi = np.array(box.lo)[None], np.array(box.hi)[None]
        assert box_distance(lo, hi, prep.path, prep.path).min() < r
        ends = np.array([base.start.position, base.goal.position])
        assert box_distance(lo, hi, ends, ends).min() > r
        size = np.subtract(box.hi, box.lo)
        if family is THIN_OBSTACLES:
            w = base.planner.min_obstacle_size
            assert w - 1e-9 <= size.min() <= 2 * w + 1e-9, (box, w)
        else:
            assert np.degrees(v.camera.vfov) <= np.degrees(base.camera.vfov) + 1e-9
    assert len(kinds) >= 2, kinds
    other = family.variant(prep, base, _rng(8, 0), 0)
    first = family.variant(prep, base, _rng(7, 0), 0)
    assert other.world.boxes[-1] != first.world.boxes[-1], "the seed matters"
