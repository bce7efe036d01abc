"""The occupancy store: OctoMap-compatible sensor log-odds plus the server's claim, kept apart.

Two layers answer for every voxel (DESIGN.md section 4, "Map update rules"):

- the **sensor layer**: OctoMap's probabilistic map built only from our own camera/lidar, with
  OctoMap's exact semantics (keys, ray casting, per-scan update sets, log-odds, clamping; see
  :mod:`secure3d.mapping.keys`). ``classify`` reads it like octomap-python's ``getLabels``;
- the **claim layer**: what the (untrusted) server says, occupied or free, per voxel.

Sensor evidence always overrides the claim. This is the paper's map update in the proof of the
safety theorem, with O the newly seen obstacles and "observed" the union of the frusta so far::

    C_free <- C_free u (observed \\ O)          C_obst <- (C_obst u O) \\ (observed n C_free)

so a voxel the sensor has seen free is free even if the server claims it occupied, a voxel the
sensor has seen occupied is an obstacle even if the server claims it free, and unobserved voxels
keep the server's claim. "Sensed occupied" is OctoMap's log-odds verdict *or* a sticky hit: a voxel
any scan has hit stays an obstacle for the planner even after later rays carve its log-odds below
the threshold (:mod:`secure3d.mapping.hits` gives the rule and why); ``classify``, the log-odds and
the ``.bt``/``.ot`` files stay exactly OctoMap's. Known obstacles for the planner are therefore
``sensed occupied u (claimed occupied \\ sensed free)``, and space outside the map ``bounds`` (the
server map's extent) is treated as unplannable.

Each voxel reports one :class:`Trust` level. Coordinates are metres in the world frame; voxel
``k`` spans ``[(k - 32768) r, (k - 32767) r)`` per axis for resolution ``r``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

import secure3d._numba_cache  # noqa: F401  (kernels cached in the user's cache dir)
from secure3d.errors import ConfigError, GeometryError
from secure3d.mapping import octomap_io
from secure3d.mapping.claim import (  # noqa: F401  (BOUNDARY_TOUCH, MAX_CLAIM_VOXELS: re-exported)
    BOUNDARY_TOUCH,
    MAX_CLAIM_VOXELS,
    ClaimLayer,
)
from secure3d.mapping.depth import depth_image_points, far_plane_reach, optical_axis
from secure3d.mapping.hits import HitLayer
from secure3d.mapping.keys import (
    KEY_LIMIT,
    TREE_DEPTH,
    TREE_MAX_VAL,
    check_points,
    codes_to_coords,
    coords_to_codes,
    morton_decode,
    morton_encode,
    scan_tiles,
    tile_voxel_count,
)
from secure3d.mapping.occupancy_claims import ClaimEditing
from secure3d.mapping.occupancy_files import OccupancyFiles
from secure3d.mapping.occupancy_views import ObstacleViews
from secure3d.mapping.octomap_header import MAX_FILE_BYTES  # noqa: F401  (re-exported)
from secure3d.mapping.scan import ScanTiles
from secure3d.mapping.scan_range import scan_tiles_free_range
from secure3d.mapping.sensor_model import InsertStats, OccupancyParams, Trust
from secure3d.mapping.store import LeafLayer
from secure3d.validation import is_real


def _check_resolution(resolution: object) -> float:
    if not is_real(resolution, numpy=True):
        raise ConfigError(f"resolution: expected a number, got {resolution!r}")
    r = float(resolution)
    if not (math.isfinite(r) and r > 0.0):
        raise ConfigError(f"resolution: must be finite and > 0, got {resolution!r}")
    return r


def _check_bounds(bounds: object) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    if bounds is None:
        return None
    try:
        lo, hi = (np.asarray(b, dtype=np.float64) for b in bounds)  # type: ignore[union-attr]
    except (TypeError, ValueError):
        raise ConfigError(f"bounds: expected (lo, hi), 3 numbers each, got {bounds!r}") from None
    if lo.shape != (3,) or hi.shape != (3,) or not np.all(np.isfinite(lo) & np.isfinite(hi)):
        raise ConfigError(f"bounds: expected finite (lo (3,), hi (3,)), got {bounds!r}")
    if np.any(hi <= lo):
        raise ConfigError(f"bounds: hi must exceed lo on every axis, got lo={lo} hi={hi}")
    return lo, hi


class OccupancyMap(ClaimEditing, ObstacleViews, OccupancyFiles):
    """OctoMap-compatible occupancy map with a separate layer for the server's claim.

    Parameters
    ----------
    resolution : float
        Voxel edge length (m).
    params : OccupancyParams
        Sensor model (OctoMap's defaults).
    bounds : (lo (3,), hi (3,)) or None
        The plannable region (the server map's extent, m). Outside it, :meth:`is_known_obstacle`
        is True and :meth:`known_obstacle_boxes` adds walls. None: unbounded.

    Notes
    -----
    The sensor layer is a flat hash of finest-level voxels (plus pruned leaves read from files),
    which answers exactly what OctoMap's pruned octree answers. Only the sensor layer is stored in
    ``.bt``/``.ot`` files; a ``.bt`` keeps only the binary state (OctoMap writes leaves at the
    clamping bounds), a ``.ot`` keeps the log-odds.
    """

    def __init__(
        self,
        resolution: float = 0.1,
        params: OccupancyParams = OccupancyParams(),  # noqa: B008 (frozen, immutable)
        bounds: tuple[ArrayLike, ArrayLike] | None = None,
    ) -> None:
        if not isinstance(params, OccupancyParams):
            raise ConfigError(f"params: expected OccupancyParams, got {type(params).__name__}")
        self._resolution = _check_resolution(resolution)
        self._params = params
        self._bounds = _check_bounds(bounds)
        self._sensor = LeafLayer()
        self._hits = HitLayer()  # sticky hits: the planner's safety layer (mapping/hits.py)
        self._claim = ClaimLayer()  # the server's claims (mapping/claim.py)
        self._version = 0
        # Merged obstacle boxes by (max_boxes, include_bounds, close_gaps). Copies share this dict
        # until either changes (``_changed`` gives the changed map a fresh one), so what one copy
        # merges serves every copy with the same content.
        self._box_cache: dict[tuple[int | None, bool, int], tuple[NDArray, NDArray]] = {}

    # ------------------------------------------------------------------ basic properties

    @property
    def resolution(self) -> float:
        """Voxel edge length (m)."""
        return self._resolution

    @property
    def params(self) -> OccupancyParams:
        return self._params

    @property
    def bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """The plannable region (lo, hi), or None."""
        if self._bounds is None:
            return None
        return self._bounds[0].copy(), self._bounds[1].copy()

    @property
    def version(self) -> int:
        """Increases with every change (for caches of derived data)."""
        return self._version

    def __len__(self) -> int:
        """Number of finest-level voxels with sensor evidence."""
        return len(self._sensor)

    @property
    def claimed_count(self) -> int:
        """Number of voxels the server claims, occupied or free."""
        return len(self._claim)

    def __repr__(self) -> str:
        return (
            f"OccupancyMap(resolution={self._resolution}, sensed={len(self)}, "
            f"claimed={len(self._claim)})"
        )

    def copy(self) -> OccupancyMap:
        """Independent deep copy."""
        out = OccupancyMap.__new__(OccupancyMap)
        out._resolution = self._resolution
        out._params = self._params
        out._bounds = (
            None if self._bounds is None else (self._bounds[0].copy(), self._bounds[1].copy())
        )
        out._sensor = self._sensor.copy()
        out._hits = self._hits.copy()
        out._claim = self._claim.copy()
        out._version = self._version
        out._box_cache = self._box_cache  # shared until either map changes
        return out

    def _changed(self) -> None:
        self._version += 1
        self._box_cache = {}

    # ------------------------------------------------------------------ sensor updates

    def insert_point_cloud(
        self,
        points: ArrayLike,
        origin: ArrayLike,
        max_range: float | None = None,
        discretize: bool = False,
        clear_range: float | None = None,
        box: ArrayLike | None = None,
        free_range: float | None = None,
        free_axis: ArrayLike | None = None,
    ) -> InsertStats:
        """Insert one scan, exactly as OctoMap's ``insertPointCloud``; with ``box``, only its
        updates of voxels that meet the box; with ``free_range``, clearing space only near the
        sensor.

        Parameters
        ----------
        points : (n, 3) float
            End points in the world frame (m). Rows with NaN/inf, and rows whose end lies outside
            the key range, are skipped and counted.
        origin : (3,) float
            Sensor position (m).
        max_range : float or None
            Beams longer than this (m) only clear space up to it. None or inf: no limit.
        discretize : bool
            OctoMap's ``discretize`` flag: one ray per distinct end voxel, to its centre (see
            :func:`secure3d.mapping.keys.scan_update`). Several times faster for depth images.
        clear_range : float or None
            How far beams longer than ``max_range`` clear space (m), at most ``max_range``; None:
            ``max_range`` (OctoMap).
        box : ((3,), (3,)) float or None
            Corners (lo, hi) of the region of interest (m), such as the planning domain: voxels
            outside it are not updated (see :func:`secure3d.mapping.scan.scan_update`). Not
            OctoMap's BBX mode, which drops every ray whose end lies outside its box.
        free_range : float or None
            Each ray clears space only within this distance (m) of ``origin``; hits still count
            out to ``max_range`` (:func:`secure3d.mapping.scan_range.scan_tiles_free_range`).
            None: as OctoMap. The closed loop passes the camera's observed range, out to which a
            frame surely hits an obstacle of the guaranteed size, so free means *seen* free.
        free_axis : (3,) float or None
            With ``free_range``: a unit vector along which ``free_range`` limits the depth (a
            plane, a camera's z-depth) instead of the distance.

        Returns
        -------
        InsertStats

        Raises
        ------
        GeometryError
            ``points`` is not (n, 3), ``origin`` is not finite / outside the key range, or ``box``
            is not two finite corners with lo <= hi.
        ConfigError
            ``max_range`` is negative or NaN.
        """
        upd = self._scan(
            points, origin, max_range, discretize, clear_range, box, free_range, free_axis
        )
        p = self._params
        self._sensor.add_logodds_tiles(
            upd.blocks, upd.masks, p.miss_log, p.clamp_min_log, p.clamp_max_log
        )
        self._sensor.add_logodds(upd.occupied, p.hit_log, p.clamp_min_log, p.clamp_max_log)
        self._hits.add(upd.occupied)
        self._changed()
        return InsertStats(
            upd.points_used,
            upd.skipped_nonfinite,
            upd.skipped_out_of_range,
            upd.clipped,
            tile_voxel_count(upd.masks),
            int(upd.occupied.size),
            upd.occupied,
            upd.rays,
        )

    def _scan(
        self,
        points: ArrayLike,
        origin: ArrayLike,
        max_range: float | None,
        discretize: bool,
        clear_range: float | None,
        box: ArrayLike | None,
        free_range: float | None,
        free_axis: ArrayLike | None,
    ) -> ScanTiles:
        """The scan's updates (:meth:`insert_point_cloud`'s parameters, validated)."""
        mr = self._check_max_range(max_range)
        cr = self._check_max_range(clear_range, "clear_range")
        res, disc = self._resolution, bool(discretize)
        if free_range is None:
            return scan_tiles(points, origin, res, mr, disc, clear_range=cr, box=box)
        fr = self._check_max_range(free_range, "free_range")
        fr = math.inf if fr is None else fr
        return scan_tiles_free_range(points, origin, res, mr, fr, disc, cr, box, free_axis)

    @staticmethod
    def _check_max_range(max_range: float | None, what: str = "max_range") -> float | None:
        if max_range is None:
            return None
        if not is_real(max_range, numpy=True):
            raise ConfigError(f"{what}: expected a number or None, got {max_range!r}")
        mr = float(max_range)
        if math.isnan(mr) or mr < 0.0:
            raise ConfigError(f"{what}: must be >= 0 (or None), got {max_range!r}")
        return None if math.isinf(mr) else mr

    def insert_depth_image(
        self,
        depth: ArrayLike,
        intrinsics: ArrayLike,
        cam2world: ArrayLike,
        origin: ArrayLike,
        max_range: float | None,
        discretize: bool = False,
        far_kind: str = "range",
        box: ArrayLike | None = None,
        free_range: float | None = None,
    ) -> InsertStats:
        """Insert a z-depth image from a pinhole camera (see :func:`depth_image_points`).

        Finite depths are hits, ``inf`` pixels are "no return" and only clear space, NaN or
        non-positive pixels are skipped (counted as non-finite). With ``far_kind="range"`` the
        sensor sees up to ``max_range`` in every direction: OctoMap's rule as it is (hits farther
        than ``max_range`` only clear space, and no returns clear up to ``max_range``). With
        ``far_kind="depth"`` it sees up to the z-depth ``max_range``, which lies farther than
        ``max_range`` off the axis: every hit up to that plane is inserted as a hit (OctoMap's
        ``maxrange`` set beyond its farthest corner, :func:`far_plane_reach`), depths beyond it
        count as no returns, and no returns clear space only up to the range ``max_range`` (the
        largest ball the sensor surely saw empty; ``clear_range`` of :meth:`insert_point_cloud`).
        Inserting a z-depth image with the Euclidean rule would drop the hits near the far corners
        of the field of view that a planner counts as seen.

        Parameters
        ----------
        depth : (H, W) float
            z-depth (m).
        intrinsics : (3, 3) float or (4,) float
            Camera matrix K, or ``(fx, fy, cx, cy)`` in pixels.
        cam2world : (3, 3) float
            Rotation from the camera frame (x right, y down, z forward) to the world frame.
        origin : (3,) float
            Camera centre in the world (m).
        max_range : float or None
            Maximum sensing range (m); with None, ``inf`` pixels are skipped.
        discretize : bool
            One ray per distinct end voxel (OctoMap's ``discretize``; see
            :meth:`insert_point_cloud`).
        far_kind : ``"range"`` or ``"depth"``
            What ``max_range`` limits (the scenario's ``camera.far_kind``).
        box : ((3,), (3,)) float or None
            Update only voxels that meet this box (see :meth:`insert_point_cloud`).
        free_range : float or None
            Clear space only within this distance (m) of ``origin``, in ``far_kind`` as
            ``max_range``: a z-depth or a Euclidean range (see :meth:`insert_point_cloud`).

        Returns
        -------
        InsertStats
        """
        mr = self._check_max_range(max_range)
        points = depth_image_points(depth, intrinsics, cam2world, origin, mr, far_kind)
        axis = None
        if far_kind == "depth" and free_range is not None:
            axis = optical_axis(cam2world)
        if far_kind != "depth" or mr is None:
            return self.insert_point_cloud(
                points, origin, mr, discretize, None, box, free_range, axis
            )
        # a discretised hit moves to its voxel's centre, up to half a diagonal farther
        reach = far_plane_reach(np.shape(depth), intrinsics, mr) + self._resolution
        return self.insert_point_cloud(points, origin, reach, discretize, mr, box, free_range, axis)

    # ------------------------------------------------------------------ point queries

    def _codes(self, points: ArrayLike) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
        return coords_to_codes(check_points(points), self._resolution)

    def _sensor_values(self, codes: NDArray[np.int64]) -> NDArray[np.float32]:
        return self._sensor.get(codes)

    def _claim_state(self, codes: NDArray[np.int64]) -> NDArray[np.int8]:
        """-1 no claim, 0 claimed free, 1 claimed occupied."""
        return self._claim.state(codes)

    def classify(self, points: ArrayLike) -> NDArray[np.int8]:
        """Sensor-layer state per point, octomap-python's ``getLabels`` convention.

        Parameters
        ----------
        points : (n, 3) float

        Returns
        -------
        (n,) int8
            -1 unknown (also non-finite or out of the key range), 0 free, 1 occupied.
        """
        codes, _ = self._codes(points)
        val = self._sensor_values(codes)
        out = np.full(codes.shape, -1, np.int8)
        known = ~np.isnan(val)
        out[known] = val[known] >= self._params.threshold_log
        return out

    def observed(self, points: ArrayLike) -> NDArray[np.bool_]:
        """Whether the sensor has evidence (free or occupied) at each point's voxel, (n,) bool."""
        codes, _ = self._codes(points)
        return ~np.isnan(self._sensor_values(codes))

    def trust(self, points: ArrayLike) -> NDArray[np.uint8]:
        """:class:`Trust` of each point's voxel, (n,) uint8: sensor evidence first, then claim."""
        codes, _ = self._codes(points)
        return self._trust_of_codes(codes)

    def _trust_of_codes(self, codes: NDArray[np.int64]) -> NDArray[np.uint8]:
        val = self._sensor_values(codes)
        claim = self._claim_state(codes)
        out = np.full(codes.shape, Trust.UNKNOWN, np.uint8)
        out[claim == 0] = Trust.CLAIMED_FREE
        out[claim == 1] = Trust.CLAIMED_OCCUPIED
        sensed = ~np.isnan(val)
        occ = self._hits.contains(codes)
        occ[sensed] |= val[sensed] >= self._params.threshold_log
        out[sensed & ~occ] = Trust.SENSED_FREE
        out[sensed & occ] = Trust.SENSED_OCCUPIED
        return out

    def in_bounds(self, points: ArrayLike) -> NDArray[np.bool_]:
        """Whether each point lies in the plannable region (closed box), ``(n,) bool``."""
        p = check_points(points)
        if self._bounds is None:
            return np.all(np.isfinite(p), axis=1)
        lo, hi = self._bounds
        return np.all((p >= lo) & (p <= hi), axis=1)

    def is_known_obstacle(self, points: ArrayLike) -> NDArray[np.bool_]:
        """Known obstacle at each point (``(n,) bool``): sensed occupied, or claimed occupied and
        not sensed free, or outside ``bounds`` (unplannable)."""
        t = self.trust(points)
        return (
            (t == Trust.SENSED_OCCUPIED) | (t == Trust.CLAIMED_OCCUPIED) | ~self.in_bounds(points)
        )

    def is_known_obstacle_sensed(self, codes: ArrayLike) -> NDArray[np.bool_]:
        """:meth:`is_known_obstacle` of voxels the sensor has evidence on (the ``occupied_codes``
        of an insertion, say), by Morton code: their trust is their log-odds or a sticky hit, so
        the claim layer need not be looked up. Raises :class:`GeometryError` if one of them is unsensed."""
        c = np.asarray(codes, dtype=np.int64).ravel()
        val = self._sensor_values(c)
        if np.isnan(val).any():
            raise GeometryError(
                f"is_known_obstacle_sensed: {int(np.isnan(val).sum())} of {c.size} voxels have no"
                " sensor evidence"
            )
        return (
            (val >= self._params.threshold_log)
            | self._hits.contains(c)
            | ~self.in_bounds(codes_to_coords(c, self._resolution))
        )

    # ------------------------------------------------------------------ voxel sets

    def _sensor_voxels(self) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
        return self._sensor.voxels()

    def occupied_voxels(self) -> NDArray[np.float64]:
        """Centres of sensed occupied voxels, ``(n, 3) float64`` sorted in octree order."""
        codes, vals = self._sensor_voxels()
        return codes_to_coords(codes[vals >= self._params.threshold_log], self._resolution)

    def free_voxels(self) -> NDArray[np.float64]:
        """Centres of sensed free voxels, ``(n, 3) float64`` sorted in octree order."""
        codes, vals = self._sensor_voxels()
        return codes_to_coords(codes[vals < self._params.threshold_log], self._resolution)

    @property
    def claims_free(self) -> bool:
        """Whether the server claims any voxel free, as a scan does where its rays passed (a list
        of obstacles claims only occupied voxels, and leaves free space undescribed)."""
        return not bool(self._claim.occupied.all())

    def claimed_voxels(self, occupied: bool = True) -> NDArray[np.float64]:
        """Centres of voxels the server claims occupied (or free), ``(n, 3) float64``."""
        return codes_to_coords(
            self._claim.codes[self._claim.occupied == occupied], self._resolution
        )

    def leaves(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float32]]:
        """Sensor layer in pruned form (as OctoMap would store it, identical siblings merged).

        Returns
        -------
        centres : (n, 3) float64
        sizes : (n,) float64
            Edge length of each leaf (m).
        log_odds : (n,) float32
        """
        starts, depths, vals = octomap_io.prune(*self._sensor.leaves())
        sizes = self._resolution * np.exp2(TREE_DEPTH - depths.astype(np.float64))
        corner = codes_to_coords(starts, self._resolution) - 0.5 * self._resolution
        return corner + 0.5 * sizes[:, None], sizes, vals

    def _known_obstacle_runs(self) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """Morton codes of the claimed occupied voxels with no sensor evidence, and of the sensed
        occupied voxels (log-odds occupied, or hit once: sticky): two disjoint sorted runs of
        unique codes."""
        # the voxels at or above the threshold and the hit ones with sensor evidence: only the
        # occupied few are sorted, not every sensed voxel
        above = self._sensor.voxels_at_least(self._params.threshold_log)
        hits = np.asarray(self._hits.codes)
        hits = hits[~np.isnan(self._sensor_values(hits))]
        sensed_occ = np.union1d(above, hits).astype(np.int64, copy=False)
        claimed = self._claim.occupied_codes()
        return claimed[np.isnan(self._sensor_values(claimed))], sensed_occ

    def _known_obstacle_codes(self) -> NDArray[np.int64]:
        # The union of two sorted runs: timsort merges them in linear time.
        return np.sort(np.concatenate(self._known_obstacle_runs()), kind="stable")

    def known_obstacles(self) -> tuple[NDArray[np.float64], NDArray[np.uint8]]:
        """The known obstacle voxels with their :class:`Trust`, as ``(known_obstacle_voxels(),
        trust(...))`` would give them but without looking the trust up again: claimed ones
        (``CLAIMED_OCCUPIED``) first, then sensed ones (``SENSED_OCCUPIED``), each in Morton order.

        Returns
        -------
        centres : (n, 3) float64
        trust : (n,) uint8
        """
        claimed, sensed = self._known_obstacle_runs()
        trust = np.repeat(
            np.array([Trust.CLAIMED_OCCUPIED, Trust.SENSED_OCCUPIED], dtype=np.uint8),
            [len(claimed), len(sensed)],
        )
        return codes_to_coords(np.concatenate([claimed, sensed]), self._resolution), trust

    def known_obstacle_voxels(self) -> NDArray[np.float64]:
        """Centres of known obstacle voxels: sensed occupied u (claimed occupied \\ sensed free).

        Returns
        -------
        (n, 3) float64
        """
        return codes_to_coords(self._known_obstacle_codes(), self._resolution)

    def voxels_in_box(
        self, lo: ArrayLike, hi: ArrayLike
    ) -> tuple[NDArray[np.float64], NDArray[np.uint8]]:
        """Voxels with any information whose centres lie in the box ``[lo, hi]``.

        Parameters
        ----------
        lo, hi : (3,) float
            Box corners (m).

        Returns
        -------
        centres : (n, 3) float64
        trust : (n,) uint8
            :class:`Trust` of each (never UNKNOWN).
        """
        lo_a, hi_a = self._check_box(lo, hi)
        klo = np.ceil(lo_a / self._resolution - 0.5).astype(np.int64) + TREE_MAX_VAL
        khi = np.floor(hi_a / self._resolution - 0.5).astype(np.int64) + TREE_MAX_VAL
        klo = np.clip(klo, 0, KEY_LIMIT - 1)
        khi = np.clip(khi, 0, KEY_LIMIT - 1)
        if np.any(khi < klo):
            return np.empty((0, 3)), np.empty(0, np.uint8)
        n_box = float(np.prod((khi - klo + 1).astype(np.float64)))
        n_known = len(self._sensor) + len(self._claim)
        if n_box <= 4 * max(n_known, 1 << 16):
            # Small box: look every voxel of it up.
            axes = [np.arange(a, b + 1) for a, b in zip(klo, khi, strict=True)]
            keys = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
            codes = np.sort(morton_encode(keys))
        else:
            sensor_codes, _ = self._sensor_voxels()
            codes = np.union1d(sensor_codes, self._claim.codes)
            keys = morton_decode(codes)
            inside = np.all((keys >= klo) & (keys <= khi), axis=1)
            codes = codes[inside]
        t = self._trust_of_codes(codes)
        known = t != Trust.UNKNOWN
        return codes_to_coords(codes[known], self._resolution), t[known]

    @staticmethod
    def _check_box(lo: ArrayLike, hi: ArrayLike) -> tuple[NDArray, NDArray]:
        lo_a = np.asarray(lo, dtype=np.float64)
        hi_a = np.asarray(hi, dtype=np.float64)
        if (
            lo_a.shape != (3,)
            or hi_a.shape != (3,)
            or not np.all(np.isfinite(lo_a) & np.isfinite(hi_a))
        ):
            raise GeometryError(f"box: expected finite lo (3,), hi (3,), got {lo!r}, {hi!r}")
        return lo_a, hi_a
