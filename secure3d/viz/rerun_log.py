"""Rerun replay of a closed-loop run: ``rerun FILE.rrd`` shows what the robot knew and did.

:class:`RerunRecorder` writes one ``.rrd`` with a default blueprint: a 3D view of the true world,
the server's claimed map, the robot's belief voxels coloured by trust class, the camera frustum and
depth image following the vehicle, the current plan with its reactive ellipsoids (paper eq.
ReactEllipse), the realised path; a 2D depth view, time series (speed, clearance, solve time), an
event log and a legend. Everything is on the ``sim_time`` timeline (seconds of simulated time).

Rules it keeps:

- it logs through its own :class:`rerun.RecordingStream`, never the global one, so library users'
  recordings are untouched (Rerun's examples do the same);
- no wall-clock data: the ``log_time`` timeline and the recording properties (start time) are off
  and the recording id is derived from the scenario and seed (:func:`recording_id`), so two runs
  with the same seed log the same data. The files are still not byte-identical: Rerun stamps every
  chunk and row with a TUID (wall-clock nanoseconds plus a random counter) and gives the blueprint
  a random store id, and rerun-sdk 0.41 offers no way to seed either;
- the file appears atomically: data go to a unique ``.<name>.<pid>.<random>.part`` and are renamed to ``path`` by
  :meth:`RerunRecorder.close`; an exception or ``KeyboardInterrupt`` inside a
  ``with RerunRecorder(...)`` block (or :meth:`RerunRecorder.abort`) deletes the partial file.

Entity layout (all under ``/world`` share the world frame, z up)::

    world/bounds                     static wireframe box
    world/truth/obstacles            static Boxes3D (hidden ones under world/truth/hidden)
    world/truth/meshes/<name>        static Mesh3D
    world/server/claimed             static wireframe Boxes3D of the server map (phantoms marked)
    world/server/meshes/<name>       static translucent Mesh3D of claimed mesh obstacles
    world/belief                     Boxes3D per voxel, class_id = trust class (AnnotationContext)
    world/camera                     Transform3D (camera pose)
    world/camera/image               Pinhole (frustum) ; world/camera/image/depth: DepthImage
    world/plans/<label>/path         LineStrips3D ; .../reactive: Ellipsoids3D
    world/robot                      Points3D (body) ; world/robot/trail: LineStrips3D
    metrics/<name>                   Scalars (speed, clearance, solve_time, ...)
    events                           TextLog
    legend                           static TextDocument (markdown)
"""

from __future__ import annotations

import contextlib
import os
import uuid
import weakref
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from secure3d._deps import rerun as _rerun
from secure3d.errors import ConfigError, GeometryError, SimulationError
from secure3d.mapping.surface import surface_mask
from secure3d.outputs import commit_temporary, discard_temporary, temporary_path
from secure3d.world.spec import Bounds, Box, MeshObstacle

#: Trust classes of the robot's map (same codes as ``secure3d.mapping.occupancy.Trust``):
#: code -> (label, RGBA). Free space is drawn faint so occupied voxels stay readable.
TRUST_CLASSES: dict[int, tuple[str, tuple[int, int, int, int]]] = {
    0: ("unknown", (128, 128, 128, 40)),
    1: ("claimed free", (120, 170, 255, 25)),
    2: ("claimed occupied", (255, 165, 0, 200)),
    3: ("sensed free", (80, 200, 120, 25)),
    4: ("sensed occupied", (220, 30, 30, 230)),
}

#: Namespace of :func:`recording_id` (a fixed random UUID: ids are stable across versions).
_RECORDING_NAMESPACE = uuid.UUID("6b1f1c5e-2f4e-4c59-9d7a-3f1f0d9b8a21")

_TRUE_COLOR = (150, 150, 150, 255)
_HIDDEN_COLOR = (25, 25, 25, 255)
_CLAIMED_COLOR = (230, 60, 60, 255)
_PHANTOM_COLOR = (200, 0, 200, 255)
_PLAN_COLORS = {"secure": (30, 110, 230, 255), "baseline": (240, 130, 20, 255)}
_OTHER_PLAN_COLOR = (120, 60, 200, 255)
_ELLIPSOID_ALPHA = 60
_ROBOT_COLOR = (20, 20, 200, 255)
_LEVELS = ("TRACE", "DEBUG", "INFO", "WARN", "ERROR", "CRITICAL")


def recording_id(scenario_name: str, seed: int) -> str:
    """Deterministic recording id for a run of ``scenario_name`` with ``seed`` (a UUID5 string)."""
    return str(uuid.uuid5(_RECORDING_NAMESPACE, f"{scenario_name}\x00{int(seed)}"))


def ellipsoid_axes(shapes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Half-sizes and rotations of ellipsoids ``E = {c + M z : |z| <= 1}``.

    M = V diag(s) V^T (symmetric positive definite), so E is the axis-aligned ellipsoid with
    half-sizes ``s`` rotated by V (paper eq. ReactEllipse, the R sqrt(Q) R^T form).

    Parameters
    ----------
    shapes : (K, 3, 3) float
        The matrices M.

    Returns
    -------
    half_sizes : (K, 3) float
    quaternions_xyzw : (K, 4) float
        Rotation V (made proper) as Rerun's ``xyzw`` quaternions.
    """
    M = np.asarray(shapes, dtype=float).reshape(-1, 3, 3)
    s, V = np.linalg.eigh(0.5 * (M + np.swapaxes(M, -1, -2)))
    # eigh may return a reflection; flipping one eigenvector keeps M and makes V a rotation.
    V[..., :, 0] *= np.sign(np.linalg.det(V))[:, None]
    return s, Rotation.from_matrix(V).as_quat()


def _rgba(color: tuple[int, int, int, int], alpha: int | None = None) -> tuple[int, int, int, int]:
    return color if alpha is None else (*color[:3], alpha)


def _part_path(path: Path) -> Path:
    return temporary_path(path)  # unique: two runs writing one path never share it


def _remove_quietly(path: Path) -> None:
    with contextlib.suppress(FileNotFoundError):
        path.unlink()


class RerunRecorder:
    """Writes a simulation replay to an ``.rrd`` file, atomically.

    Parameters
    ----------
    path : str or Path
        Output file (conventionally ``*.rrd``); its folder must exist.
    application_id : str
        Rerun application id (blueprints are remembered per application).
    recording_id : str, optional
        Defaults to a UUID5 of the file name; pass :func:`recording_id` (scenario, seed) for runs.
    recording_name : str, optional
        Shown in the viewer; defaults to the file stem.
    trail_period : float
        Sim-time seconds between re-logs of the full realised path (the current position is
        logged on every :meth:`log_state`). Re-logging the whole path at every step would make
        the file grow quadratically with the run length.
    image_plane_distance : float
        Depth (m) at which the viewer draws the camera frustum's image plane.

    Examples
    --------
    >>> with RerunRecorder("run.rrd", recording_id=recording_id("corner", 0)) as rec:
    ...     rec.log_world(true_boxes=world.boxes)
    ...     rec.log_state(0.0, p, v, speed=0.0, clearance=1.2)
    """

    #: A real recording (the null recorder of :mod:`secure3d.simulation.recording` says False).
    recording = True

    def __init__(
        self,
        path: str | os.PathLike[str],
        application_id: str = "secure3d",
        recording_id: str | None = None,
        *,
        recording_name: str | None = None,
        trail_period: float = 0.1,
        image_plane_distance: float = 1.0,
    ) -> None:
        self.path = Path(path)
        if not self.path.parent.is_dir():
            raise ConfigError(f"path: folder {str(self.path.parent)!r} does not exist")
        if not (np.isfinite(trail_period) and trail_period >= 0):
            raise ConfigError(f"trail_period: must be finite and >= 0, got {trail_period!r}")
        if not (np.isfinite(image_plane_distance) and image_plane_distance > 0):
            raise ConfigError(
                f"image_plane_distance: must be finite and > 0, got {image_plane_distance!r}"
            )
        self.part_path = _part_path(self.path)
        self.trail_period = float(trail_period)
        self.image_plane_distance = float(image_plane_distance)
        rr = _rerun()
        self._rr = rr
        rid = recording_id or str(uuid.uuid5(_RECORDING_NAMESPACE, self.path.name))
        self._rec = rr.RecordingStream(application_id, recording_id=rid, send_properties=False)
        self._rec.set_log_time_enabled(False)
        self._rec.set_log_tick_enabled(False)
        _remove_quietly(self.part_path)
        self._rec.save(self.part_path, default_blueprint=default_blueprint())
        # An abandoned recorder (never closed) must not leave a half-written file behind.
        self._finalizer = weakref.finalize(self, _abandon, self._rec, self.part_path)
        self._rec.send_recording_name(recording_name or self.path.stem)
        self._closed = False
        self._trail: list[np.ndarray] = []
        self._last_trail_time = -np.inf
        self._series_named: set[str] = set()
        self._log_static_legend()

    # -- lifecycle ----------------------------------------------------------------------------

    def __enter__(self) -> RerunRecorder:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self) -> Path:
        """Finish the file and move it into place; returns the final path. Idempotent."""
        if self._closed:
            return self.path
        self._closed = True
        self._finalizer.detach()
        self._rec.flush()
        self._rec.disconnect()
        return commit_temporary(self.part_path, self.path)

    def abort(self) -> None:
        """Stop recording and delete the partial file (the final ``path`` is never touched)."""
        if self._closed:
            return
        self._closed = True
        self._finalizer.detach()
        _abandon(self._rec, self.part_path)

    def _at(self, t: float) -> Any:
        if self._closed:
            raise SimulationError(f"RerunRecorder for {str(self.path)!r} is closed")
        t = float(t)
        if not np.isfinite(t):
            raise ConfigError(f"t: simulation time must be finite, got {t!r}")
        self._rec.set_time("sim_time", duration=t)
        return self._rec

    def _static(self) -> Any:
        if self._closed:
            raise SimulationError(f"RerunRecorder for {str(self.path)!r} is closed")
        return self._rec

    # -- static content -------------------------------------------------------------------------

    def _log_static_legend(self) -> None:
        rr = self._rr
        self._rec.log(
            "world/belief",
            rr.AnnotationContext(
                [
                    rr.AnnotationInfo(id=k, label=lab, color=c)
                    for k, (lab, c) in TRUST_CLASSES.items()
                ]
            ),
            static=True,
        )
        rows = "\n".join(f"| {k} | {lab} | rgba{c} |" for k, (lab, c) in TRUST_CLASSES.items())
        text = (
            "# secure3d replay\n\n"
            "**Belief voxels** (`world/belief`), coloured by trust class (sensor evidence always"
            " overrides the server's claim):\n\n| code | class | colour |\n|---|---|---|\n"
            f"{rows}\n\n"
            "**Truth** grey, **hidden** obstacles (deleted from the server map) near-black;"
            " **server claim** red wireframe, **phantoms** magenta.\n\n"
            "**Plans**: secure blue, baseline orange; translucent ellipsoids are the reactive sets"
            " S_r(x) at the nodes (paper eq. ReactEllipse).\n"
        )
        self._rec.log(
            "legend", rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN), static=True
        )

    def log_world(
        self,
        true_boxes: Sequence[Box] = (),
        true_meshes: Sequence[MeshObstacle] = (),
        claimed_boxes: Sequence[Box] = (),
        claimed_meshes: Sequence[MeshObstacle] = (),
        hidden_names: Sequence[str] = (),
        bounds: Bounds | None = None,
        true_voxels: np.ndarray | None = None,
        true_voxel_colors: np.ndarray | None = None,
    ) -> None:
        """Log the true world and the server's claim (static: they do not change during a run).

        ``true_voxels`` ((n, 2, 3) ``[lo, hi]``, ``world.octomap``'s occupied leaves) are logged
        as solid boxes under ``world/truth/voxels``, in ``true_voxel_colors`` ((n, 3) uint8, a
        colour tree's) where given.

        Hidden obstacles (``hidden_names``: true obstacles the server does not report) are drawn
        near-black under ``world/truth/hidden``; claimed obstacles absent from the truth (by name)
        are phantoms, drawn magenta.
        """
        rec = self._static()
        if bounds is not None:
            rec.log(
                "world/bounds",
                self._rr.Boxes3D(
                    mins=[bounds.lo],
                    sizes=[np.subtract(bounds.hi, bounds.lo)],
                    colors=[(90, 90, 90, 255)],
                    fill_mode="MajorWireframe",
                ),
                static=True,
            )
        self._log_truth(rec, true_boxes, true_meshes, set(hidden_names))
        if true_voxels is not None and len(true_voxels):
            colors = (
                [_TRUE_COLOR] * len(true_voxels)
                if true_voxel_colors is None
                else np.asarray(true_voxel_colors, np.uint8)
            )
            rec.log(
                "world/truth/voxels",
                self._rr.Boxes3D(
                    mins=true_voxels[:, 0],
                    sizes=true_voxels[:, 1] - true_voxels[:, 0],
                    colors=colors,
                    fill_mode="Solid",
                ),
                static=True,
            )
        true_names = {o.name for o in (*true_boxes, *true_meshes)}
        self._log_claim(rec, claimed_boxes, claimed_meshes, true_names)

    def _log_truth(
        self,
        rec: Any,
        boxes: Sequence[Box],
        meshes: Sequence[MeshObstacle],
        hidden: set[str],
    ) -> None:
        """The true obstacles: solid, the hidden ones near-black under ``world/truth/hidden``."""
        rr = self._rr
        for group, keep in (("obstacles", False), ("hidden", True)):
            sel = [b for b in boxes if (b.name in hidden) == keep]
            if sel:
                rec.log(
                    f"world/truth/{group}",
                    rr.Boxes3D(
                        mins=[b.lo for b in sel],
                        sizes=[np.subtract(b.hi, b.lo) for b in sel],
                        labels=[b.name for b in sel],
                        colors=[_HIDDEN_COLOR if keep else _TRUE_COLOR] * len(sel),
                        fill_mode="Solid",
                        show_labels=False,
                    ),
                    static=True,
                )
        for m in meshes:
            color = _HIDDEN_COLOR if m.name in hidden else _TRUE_COLOR
            rec.log(
                f"world/truth/meshes/{rr.escape_entity_path_part(m.name)}",
                rr.Mesh3D(
                    vertex_positions=m.vertices,
                    triangle_indices=m.faces,
                    albedo_factor=color,
                ),
                static=True,
            )

    def _log_claim(
        self,
        rec: Any,
        boxes: Sequence[Box],
        meshes: Sequence[MeshObstacle],
        true_names: set[str],
    ) -> None:
        """The server's claim, wireframe; obstacles absent from the truth (phantoms) magenta."""
        rr = self._rr
        if boxes:
            rec.log(
                "world/server/claimed",
                rr.Boxes3D(
                    mins=[b.lo for b in boxes],
                    sizes=[np.subtract(b.hi, b.lo) for b in boxes],
                    labels=[_claim_label(b.name, true_names) for b in boxes],
                    colors=[_claim_color(b.name, true_names) for b in boxes],
                    fill_mode="MajorWireframe",
                    show_labels=False,
                ),
                static=True,
            )
        for m in meshes:
            rec.log(
                f"world/server/meshes/{rr.escape_entity_path_part(m.name)}",
                rr.Mesh3D(
                    vertex_positions=m.vertices,
                    triangle_indices=m.faces,
                    albedo_factor=_rgba(_claim_color(m.name, true_names), 70),
                ),
                static=True,
            )

    # -- time-varying content -----------------------------------------------------------------

    def log_belief(
        self, t: float, centres: np.ndarray, trust: np.ndarray, resolution: float
    ) -> None:
        """Log the robot's voxel map at sim time ``t``.

        Parameters
        ----------
        centres : (n, 3) float
            Voxel centres (m).
        trust : (n,) uint8
            Trust class per voxel (:data:`TRUST_CLASSES`); unknown voxels (0) are not drawn, nor
            are voxels enclosed by drawn ones (all six face neighbours drawn: they cannot show).
        resolution : float
            Voxel edge (m).
        """
        c = np.asarray(centres, dtype=float).reshape(-1, 3)
        k = np.asarray(trust).reshape(-1)
        if len(k) != len(c):
            raise GeometryError(f"trust: expected {len(c)} classes, got {len(k)}")
        if not (np.isfinite(resolution) and resolution > 0):
            raise ConfigError(f"resolution: must be finite and > 0, got {resolution!r}")
        bad = ~np.isin(k, list(TRUST_CLASSES))
        if np.any(bad):
            raise GeometryError(f"trust: unknown class {int(k[bad][0])}")
        keep = np.flatnonzero(k != 0)
        # Solid boxes enclose the voxels whose six face neighbours are all drawn: leave those out
        # (the blind corner's 221k known voxels are 45k boxes to draw, encode and store).
        keep = keep[surface_mask(np.floor(c[keep] / float(resolution)).astype(np.int64))]
        # One half size for all: Rerun repeats the last half size for the remaining centres.
        self._at(t).log(
            "world/belief",
            self._rr.Boxes3D(
                centers=c[keep].astype(np.float32),
                half_sizes=np.full((1, 3), 0.5 * float(resolution), dtype=np.float32),
                class_ids=k[keep].astype(np.uint16),
                fill_mode="Solid",
            ),
        )

    def log_camera(
        self,
        t: float,
        R_world_from_optical: np.ndarray,
        origin: np.ndarray,
        fx: float,
        fy: float,
        width: int,
        height: int,
        depth: np.ndarray | None = None,
    ) -> None:
        """Log the camera pose, its pinhole frustum and (optionally) the depth image at ``t``.

        ``depth`` : (height, width) float z-depth (m); ``inf`` (nothing in range) and ``NaN``
        (no data) are logged as 0, Rerun's "no depth". Principal point at the image centre.
        """
        rr = self._rr
        R = np.asarray(R_world_from_optical, dtype=float)
        rec = self._at(t)
        rec.log("world/camera", rr.Transform3D(translation=np.asarray(origin, float), mat3x3=R))
        rec.log(
            "world/camera/image",
            rr.Pinhole(
                focal_length=[float(fx), float(fy)],
                width=int(width),
                height=int(height),
                camera_xyz=rr.ViewCoordinates.RDF,
                image_plane_distance=self.image_plane_distance,
            ),
        )
        if depth is not None:
            d = np.asarray(depth, dtype=np.float32)
            if d.shape != (int(height), int(width)):
                raise GeometryError(f"depth: expected shape {(height, width)}, got {d.shape}")
            rec.log(
                "world/camera/image/depth",
                rr.DepthImage(np.where(np.isfinite(d), d, np.float32(0.0)), meter=1.0),
            )

    def log_plan(self, t: float, plan: Any, label: str | None = None) -> None:
        """Log a plan's path and reactive ellipsoids at ``t`` (replacing that label's previous one).

        ``plan`` needs ``positions (K, 3)``, ``ellipsoid_centers (K, 3)``, ``ellipsoid_shapes
        (K, 3, 3)`` and ``planner``; ``label`` defaults to ``plan.planner``.
        """
        rr = self._rr
        label = label or str(getattr(plan, "planner", "plan"))
        color = _PLAN_COLORS.get(label, _PLAN_COLORS.get(getattr(plan, "planner", ""), None))
        color = color or _OTHER_PLAN_COLOR
        base = f"world/plans/{rr.escape_entity_path_part(label)}"
        rec = self._at(t)
        positions = np.asarray(plan.positions, dtype=float)
        rec.log(f"{base}/path", rr.LineStrips3D([positions], colors=[color], radii=0.02))
        centres = np.asarray(plan.ellipsoid_centers, dtype=float).reshape(-1, 3)
        if len(centres):
            half, quat = ellipsoid_axes(plan.ellipsoid_shapes)
            rec.log(
                f"{base}/reactive",
                rr.Ellipsoids3D(
                    centers=centres,
                    half_sizes=half,
                    quaternions=quat,
                    colors=[_rgba(color, _ELLIPSOID_ALPHA)] * len(centres),
                    fill_mode="Solid",
                ),
            )

    def log_state(
        self,
        t: float,
        position: np.ndarray,
        velocity: np.ndarray,
        speed: float,
        clearance: float,
    ) -> None:
        """Log the vehicle at ``t``: body position and velocity arrow, realised path, speed and
        clearance time series."""
        rr = self._rr
        p = np.asarray(position, dtype=float).reshape(3)
        v = np.asarray(velocity, dtype=float).reshape(3)
        rec = self._at(t)
        rec.log("world/robot", rr.Points3D([p], radii=0.08, colors=[_ROBOT_COLOR]))
        rec.log(
            "world/robot/velocity", rr.Arrows3D(origins=[p], vectors=[v], colors=[_ROBOT_COLOR])
        )
        self._trail.append(p)
        if float(t) - self._last_trail_time >= self.trail_period:
            self._last_trail_time = float(t)
            rec.log(
                "world/robot/trail",
                rr.LineStrips3D([np.array(self._trail)], colors=[_ROBOT_COLOR], radii=0.015),
            )
        self.log_scalar(t, "speed", speed)
        self.log_scalar(t, "clearance", clearance)

    def log_scalar(self, t: float, name: str, value: float) -> None:
        """Log one time-series sample ``metrics/<name>`` at ``t`` (non-finite values are skipped:
        e.g. the clearance of an empty world)."""
        rr = self._rr
        rec = self._at(t)
        entity = f"metrics/{rr.escape_entity_path_part(name)}"
        if entity not in self._series_named:
            self._series_named.add(entity)
            rec.log(entity, rr.SeriesLines(names=[name]), static=True)
        value = float(value)
        if np.isfinite(value):
            rec.log(entity, rr.Scalars([value]))

    def log_event(self, t: float, text: str, level: str = "INFO") -> None:
        """Log a line to the event log at ``t``. ``level`` is one of TRACE DEBUG INFO WARN ERROR
        CRITICAL."""
        lvl = level.upper()
        if lvl not in _LEVELS:
            raise ConfigError(f"level: must be one of {_LEVELS}, got {level!r}")
        self._at(t).log("events", self._rr.TextLog(str(text), level=lvl))


def default_blueprint() -> Any:
    """The layout a replay opens with: 3D scene left; depth image, time series, events and legend
    stacked on the right."""
    rrb = _rerun().blueprint
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="/world", name="World (truth, claim, belief, plan)"),
            rrb.Vertical(
                rrb.Spatial2DView(origin="/world/camera/image", name="Depth camera"),
                rrb.TimeSeriesView(origin="/metrics", name="Speed, clearance, solve time"),
                rrb.Tabs(
                    rrb.TextLogView(origin="/events", name="Events"),
                    rrb.TextDocumentView(origin="/legend", name="Legend"),
                ),
                row_shares=[3, 3, 2],
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


def _claim_label(name: str, true_names: set[str]) -> str:
    return name if name in true_names else f"{name} (phantom)"


def _claim_color(name: str, true_names: set[str]) -> tuple[int, int, int, int]:
    return _CLAIMED_COLOR if name in true_names else _PHANTOM_COLOR


def _abandon(rec: Any, part_path: Path) -> None:
    with contextlib.suppress(Exception):
        rec.disconnect()
    discard_temporary(part_path)
