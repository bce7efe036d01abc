"""The world: scenario files, the true obstacles, and what the (untrusted) map server claims.

- :mod:`~secure3d.world.spec`: the frozen, validated data model (:class:`Scenario` and parts);
- :mod:`~secure3d.world.scenario`: ``maps/*.yaml`` to :class:`Scenario` and back;
- :mod:`~secure3d.world.meshes`: safe loading of OBJ/STL/PLY obstacles;
- :mod:`~secure3d.world.attacks`: server claims (hide, phantom, shift, stale), the robot's initial
  belief map, the true obstacles, random hidden-obstacle variants.
"""

from secure3d.world.attacks import (
    ServerClaim,
    TrueObstacles,
    belief_map,
    random_hidden_obstacle_scenarios,
    server_claim,
    true_obstacles,
)
from secure3d.world.meshes import load_mesh, mesh_from_arrays, resolve_inside
from secure3d.world.scenario import (
    load_scenario,
    save_scenario,
    scenario_from_dict,
    scenario_to_dict,
)
from secure3d.world.spec import (
    Attack,
    Bounds,
    Box,
    CameraSpec,
    GoalSpec,
    MeshObstacle,
    PlannerSpec,
    Region,
    Scenario,
    ServerMapSpec,
    SimulationSpec,
    StartSpec,
    VehicleSpec,
    World,
)

__all__ = [
    "Attack",
    "Bounds",
    "Box",
    "CameraSpec",
    "GoalSpec",
    "MeshObstacle",
    "PlannerSpec",
    "Region",
    "Scenario",
    "ServerClaim",
    "ServerMapSpec",
    "SimulationSpec",
    "StartSpec",
    "TrueObstacles",
    "VehicleSpec",
    "World",
    "belief_map",
    "load_mesh",
    "load_scenario",
    "mesh_from_arrays",
    "random_hidden_obstacle_scenarios",
    "resolve_inside",
    "save_scenario",
    "scenario_from_dict",
    "scenario_to_dict",
    "server_claim",
    "true_obstacles",
]
