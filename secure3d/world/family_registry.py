"""The scenario families shipped for campaigns, by name (see :mod:`secure3d.world.families`).

Adding a family is one entry here. The hidden-obstacle kinds ``auto``, ``corner`` and ``forest``
(:func:`secure3d.world.attacks.random_hidden_obstacle_scenarios`) stay the campaign's defaults.
"""

from __future__ import annotations

from secure3d.world.deadend_families import DEAD_END
from secure3d.world.denial_families import DENIAL
from secure3d.world.families import Family
from secure3d.world.fence_families import FENCES
from secure3d.world.passage_families import PASSAGE_WIDTH
from secure3d.world.region_attacks import REGION_ATTACKS
from secure3d.world.survey_families import SURVEY
from secure3d.world.thin_families import OCCLUSION_3D, THIN_OBSTACLES

__all__ = ["FAMILIES"]

#: Families by name.
FAMILIES: dict[str, Family] = {
    f.name: f
    for f in (
        THIN_OBSTACLES,
        OCCLUSION_3D,
        FENCES,
        DEAD_END,
        REGION_ATTACKS,
        DENIAL,
        PASSAGE_WIDTH,
        SURVEY,
    )
}
