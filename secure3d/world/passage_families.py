"""The passage-width family: the paper's passages (its Fig. ThreadNeedle) at random widths.

Variant ``i`` of a base scenario with a passage between boxes named ``wall_left`` (below the gap in
y) and ``wall_right`` (above it) moves both walls' inner faces symmetrically about the gap's
centre, to a width drawn uniformly from :data:`WIDTH_RANGE` scaled by the body: at least the body's
diameter plus :data:`MIN_SIDE_ROOM` on either side, at most :data:`MAX_WIDTH`. Nothing is hidden:
a campaign over this family measures what the paper's two passages sample, the secure planner's
time against the width (and that every flight still arrives).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from secure3d.errors import ScenarioError
from secure3d.world.families import Family
from secure3d.world.spec import Scenario

__all__ = ["PASSAGE_WIDTH", "passage_width_variant"]

#: Room (m) left on each side of the body at the narrowest width, and the widest width (m): the
#: paper's 20 cm and 50 cm passages lie inside for its 0.04 m body.
MIN_SIDE_ROOM = 0.03
MAX_WIDTH = 0.6


def _walls(base: Scenario) -> tuple[int, int]:
    names = [b.name for b in base.world.boxes]
    if "wall_left" not in names or "wall_right" not in names:
        raise ScenarioError(
            f"{base.name}: the passage_width family needs boxes 'wall_left' and 'wall_right'"
            f" (the paper_passage_* scenarios); got {names}"
        )
    left, right = names.index("wall_left"), names.index("wall_right")
    if base.world.boxes[left].hi[1] >= base.world.boxes[right].lo[1]:
        raise ScenarioError(f"{base.name}: wall_left must lie below wall_right in y")
    return left, right


def passage_width_variant(
    prepared: tuple[int, int], base: Scenario, rng: np.random.Generator, i: int
) -> Scenario:
    """Variant ``i``: ``base`` with its passage ``width`` wide (see the module doc)."""
    left, right = prepared
    boxes = list(base.world.boxes)
    narrowest = 2 * (base.vehicle.body_radius + MIN_SIDE_ROOM)
    if narrowest >= MAX_WIDTH:
        raise ScenarioError(f"{base.name}: the body is too wide for passages up to {MAX_WIDTH} m")
    width = float(rng.uniform(narrowest, MAX_WIDTH))
    centre = 0.5 * (boxes[left].hi[1] + boxes[right].lo[1])
    lo_y, hi_y = centre - width / 2, centre + width / 2
    l_hi, r_lo = list(boxes[left].hi), list(boxes[right].lo)
    l_hi[1], r_lo[1] = lo_y, hi_y
    if lo_y <= boxes[left].lo[1] or hi_y >= boxes[right].hi[1]:
        raise ScenarioError(f"{base.name}: a {width:.2f} m passage does not fit between the walls")
    boxes[left] = dataclasses.replace(boxes[left], hi=tuple(l_hi))
    boxes[right] = dataclasses.replace(boxes[right], lo=tuple(r_lo))
    world = dataclasses.replace(base.world, boxes=tuple(boxes))
    name = f"{base.name}_width_{i:03d}"
    note = f" Variant {i}: passage {100 * width:.1f} cm wide."
    return dataclasses.replace(base, name=name, world=world, description=base.description + note)


PASSAGE_WIDTH = Family(
    name="passage_width",
    description="the paper's passage at random widths (body + 6 cm to 60 cm); nothing hidden",
    prepare=_walls,
    variant=passage_width_variant,
)
