"""Geometry kernels shared by the planner (CasADi) and the safety certificate (numpy).

- :mod:`.transforms`: rotations, quaternions, the camera mounting chain.
- :mod:`.ellipsoid`: reactive-set ellipsoids ``{c + M z : |z| <= 1}`` (eq. ReactEllipse), support
  function, exact containment in half-spaces.
- :mod:`.frustum`: the camera's field of view as five half-spaces (eq. SensorModel).
- :mod:`.polytope`: boxes, convex hulls, signed distances, dual separation certificates for
  ellipsoids and line-of-sight hulls against polytopes (DESIGN.md section 4).
- :mod:`.backend`: the numpy / CasADi dispatch that lets one kernel body serve both.
"""

from secure3d.geometry.ellipsoid import (
    check_ellipsoid,
    containment_margin,
    contains_points,
    ellipsoid_from_axes,
    halfspace_margins,
    support,
    surface_points,
    volume,
)
from secure3d.geometry.frustum import (
    PinholeFrustum,
    ellipsoid_in_frustum_margin,
    frustum_corners,
    frustum_halfspaces,
    points_in_frustum,
)
from secure3d.geometry.polytope import (
    box_halfspaces,
    box_signed_distance,
    boxes_halfspaces,
    convex_hull_halfspaces,
    dual_separation_margin,
    ellipsoid_polytope_distance,
    los_hull_distance,
    los_hull_margins,
    min_box_distance,
    segment_box_intersects,
)
from secure3d.geometry.transforms import (
    BODY_FROM_OPTICAL,
    camera_rotation,
    check_rotation,
    matrix_to_quat,
    pitch_matrix,
    quat_from_axis_angle,
    quat_from_yaw,
    quat_multiply,
    quat_to_matrix,
    yaw_matrix,
)

__all__ = [
    "BODY_FROM_OPTICAL",
    "PinholeFrustum",
    "box_halfspaces",
    "box_signed_distance",
    "boxes_halfspaces",
    "camera_rotation",
    "check_ellipsoid",
    "check_rotation",
    "containment_margin",
    "contains_points",
    "convex_hull_halfspaces",
    "dual_separation_margin",
    "ellipsoid_from_axes",
    "ellipsoid_in_frustum_margin",
    "ellipsoid_polytope_distance",
    "frustum_corners",
    "frustum_halfspaces",
    "halfspace_margins",
    "los_hull_distance",
    "los_hull_margins",
    "matrix_to_quat",
    "min_box_distance",
    "pitch_matrix",
    "points_in_frustum",
    "quat_from_axis_angle",
    "quat_from_yaw",
    "quat_multiply",
    "quat_to_matrix",
    "segment_box_intersects",
    "support",
    "surface_points",
    "volume",
    "yaw_matrix",
]
