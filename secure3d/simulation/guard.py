"""The tracking guard: the robot's real state must stay where the certificate's argument holds.

The certificate (:func:`secure3d.planning.certificate.certify`) judges the *planned* states: from
each one, every point of the simulated reactive manoeuvre, grown by the body radius, is clear of the
known obstacles and was observed earlier with a clear line of sight. The safety theorem needs it of
the state the robot is *in*. A tracker follows a plan only approximately, and a plan it cannot
follow (a diff drive reversing, a gust, a tracker fault) takes the real state far from it: the
issue that started this module saw a 0.58 m position error against a 0.02 m margin, and a
collision with a wall the map knew about.

The tube. A tube of the form ``|p - p*| + L |v - v*| <= m`` around the plan, with ``m`` the
certificate's margin, is sound only with a Lipschitz bound ``L`` of the braking manoeuvre in the
initial velocity, which is about the stopping time (``t_d + v / a_b``, ~1 s here): with the
certificate's typical margins of a few millimetres it would stop the robot at every ordinary
tracking lag, and the bound itself depends on each vehicle's braking law. So the guard uses the
largest tube there is, with no Lipschitz constant: the set of states whose *own* reactive
manoeuvre passes the certificate's test (:func:`~secure3d.planning.certificate.state_margin`),
against the obstacle boxes the plan was last judged against (a superset of the known obstacles),
with "observed" meaning the followed plan's start region or a frame the camera really took (not
the planned camera poses: a robot off its plan did not look from them). A state that leaves it is
handed to the braking controller at once (``FOLLOW --OFF_TUBE--> BRAKE``).

When it checks. Every ``interval`` (0.02 s, the certificate's sampling step) while following a
secure plan, on the state one interval *ahead* under the control about to be applied: if that
state is out, braking starts now, from a state the previous check showed to be in. Most checks are
settled by :func:`ellipsoid_shown_safe`, a quick sufficient test on the reactive-set ellipsoid
(exact ellipsoid-box and line-of-sight-hull distances); the rest simulate the manoeuvre
(:func:`~secure3d.planning.certificate.state_margin`). Measured (``benchmarks/bench_guard.py``):
the flight's wall time grows 1.03-1.39x on the shipped scenarios, with identical outcomes there.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from secure3d.errors import SimulationError
from secure3d.geometry.box_index import BoxIndex
from secure3d.geometry.frustum import frustum_halfspaces
from secure3d.geometry.polytope import boxes_apart
from secure3d.planning.certificate import state_margin
from secure3d.validation import is_real

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.simulation.loop import Loop
    from secure3d.simulation.modes import Followed

__all__ = ["GuardSettings", "TrackingGuard", "ellipsoid_shown_safe"]

#: Views tried per check for the quick test, the latest first.
_QUICK_VIEWS = 8


def _support(M: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Support of the unit-ball image ``{M z : |z| <= 1}`` along ``normals`` (..., 3): |M^T n|."""
    return np.linalg.norm(normals @ M, axis=-1)


def _boxes_touching(
    lo: np.ndarray, hi: np.ndarray, a: np.ndarray, b: np.ndarray, index: BoxIndex | None = None
) -> np.ndarray:
    """Sorted indices of the boxes (lo, hi (n, 3)) that overlap the axis-aligned box [a, b],
    through their spatial ``index`` when given (the same indices; the guard judges against
    15,800-18,300 boxes on the geb079 scans)."""
    if index is not None:
        return index.overlapping(a, b)
    return np.flatnonzero(np.all((lo <= b) & (hi >= a), axis=1))


def _clear_of_boxes(
    c: np.ndarray, M: np.ndarray, lo: np.ndarray, hi: np.ndarray, index: BoxIndex | None = None
) -> bool:
    """E = {c + M z} misses every box (lo, hi (n, 3); ``index`` theirs, optional): boxes beyond
    E's bounding box are separated by a box face; the remaining ones by their exact distances to
    E, in one compiled call (:func:`~secure3d.geometry.polytope.boxes_apart`)."""
    s = _support(M, np.eye(3))
    return boxes_apart(None, c, M, lo, hi, _boxes_touching(lo, hi, c - s, c + s, index))


def _sight_clear(
    o: np.ndarray,
    c: np.ndarray,
    M: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    index: BoxIndex | None = None,
) -> bool:
    """The line-of-sight hull conv({o} ∪ E) misses every box: boxes beyond the hull's bounding
    box are separated by a box face; the remaining ones by their exact distances to the hull, in
    one compiled call."""
    s = _support(M, np.eye(3))
    a, b = np.minimum(o, c - s), np.maximum(o, c + s)
    return boxes_apart(o, c, M, lo, hi, _boxes_touching(lo, hi, a, b, index))


def ellipsoid_shown_safe(
    c: np.ndarray,
    M: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    bounds: tuple[np.ndarray, np.ndarray],
    start: tuple[np.ndarray, np.ndarray],
    rotations: np.ndarray,
    origins: np.ndarray,
    frustum: object,
    halfspaces: tuple[np.ndarray, np.ndarray] | None = None,
    index: BoxIndex | None = None,
) -> bool:
    """A quick, sufficient test that the reactive set E = {c + M z : |z| <= 1} (body included) is
    clear of the boxes ``lo, hi`` (n, 3) and of the map's edge ``bounds``, and observed: inside the
    ``start`` box (lo, hi), or inside the field of view of one of the frames ``rotations`` (k, 3, 3),
    ``origins`` (k, 3) with its line-of-sight hull conv({o} ∪ E) clear of the boxes (the NLP's
    occlusion condition, with exact distances). False means "not shown", not "unsafe": the caller
    then runs the exact test. ``halfspaces``: ``frustum_halfspaces(rotations, origins, frustum)``
    when the caller has them (the guard keeps them per set of frames); ``index``: the boxes'
    :class:`~secure3d.geometry.box_index.BoxIndex` (the same answer, without a scan of them all)."""
    if index is not None and not isinstance(index, BoxIndex):
        raise SimulationError(f"index: expected the boxes' BoxIndex, got {type(index).__name__}")
    s = _support(M, np.eye(3))  # half extents of E's bounding box
    if np.any(c - s < bounds[0]) or np.any(c + s > bounds[1]):
        return False
    if not _clear_of_boxes(c, M, lo, hi, index):
        return False
    if np.all(c - s >= start[0]) and np.all(c + s <= start[1]):
        return True
    if not len(origins):
        return False
    A, b = halfspaces or frustum_halfspaces(rotations, origins, frustum)  # (k, F, 3), (k, F)
    inside = (b - A @ c - _support(M, A)).min(axis=1)  # (k,)
    # the latest frames first: a view from near the robot is the least likely to be occluded
    candidates = np.flatnonzero(inside >= 0.0)[::-1][:_QUICK_VIEWS]
    if not len(candidates):
        return False
    return any(_sight_clear(origins[j], c, M, lo, hi, index) for j in candidates)


@dataclasses.dataclass(frozen=True)
class GuardSettings:
    """How often the guard checks: every ``interval`` simulated seconds (default the certificate's
    sampling step, 0.02 s)."""

    interval: float = 0.02

    def __post_init__(self) -> None:
        v = self.interval
        if not is_real(v) or not (0 < v < np.inf):
            raise SimulationError(f"guard setting interval: a number > 0, got {v!r}")


class TrackingGuard:
    """Checks the real state of a robot following a secure plan (see the module doc)."""

    def __init__(self, loop: Loop, settings: GuardSettings | None = None) -> None:
        self.loop = loop
        self.settings = settings or GuardSettings()
        self._R: list[np.ndarray] = []
        self._o: list[np.ndarray] = []
        self._views: tuple[np.ndarray, np.ndarray] | None = None
        #: the frames' field-of-view half-spaces for one frustum: (frustum, A (k, F, 3) and b
        #: (k, F) of the first k frames, stacked or None). Each frame's faces are computed once,
        #: when the next check after it arrives (recomputing every frame's faces on every new
        #: frame made the guard's cost grow with the square of the flight's length).
        self._faces: tuple[object, list, list, tuple[np.ndarray, np.ndarray] | None] | None = None
        self._last_check = -np.inf
        #: (lo, hi, their BoxIndex) of the boxes last judged against
        self._index: tuple[np.ndarray, np.ndarray, BoxIndex] | None = None
        #: exact checks made: (time, margin); checks the quick test settled; for tests and reports
        self.checks: list[tuple[float, float]] = []
        self.quick = 0

    def add_view(self, R: np.ndarray, o: np.ndarray) -> None:
        """A frame the camera took (rotation camera to world, origin)."""
        self._R.append(np.asarray(R, dtype=float))
        self._o.append(np.asarray(o, dtype=float))
        self._views = None  # stacked again on the next check

    def _frame_faces(self, frustum: object) -> tuple[np.ndarray, np.ndarray]:
        """``frustum_halfspaces`` of every frame so far (A (k, F, 3), b (k, F)), the same values
        as one call over the stacked frames: only the frames added since the last call are
        computed (each as a stack of one)."""
        if self._faces is None or self._faces[0] is not frustum:
            self._faces = (frustum, [], [], None)
        _, As, bs, stacked = self._faces
        if stacked is not None and len(As) == len(self._R):
            return stacked
        for R, o in zip(self._R[len(As) :], self._o[len(As) :], strict=True):
            A, b = frustum_halfspaces(R[None], o[None], frustum)
            As.append(A[0])
            bs.append(b[0])
        stacked = (np.array(As), np.array(bs))
        self._faces = (frustum, As, bs, stacked)
        return stacked

    def _box_index(self, lo: np.ndarray, hi: np.ndarray) -> BoxIndex:
        """The spatial index of the judged boxes, kept while the loop holds the same arrays (they
        change when a plan is judged against other boxes)."""
        if self._index is None or self._index[0] is not lo or self._index[1] is not hi:
            self._index = (lo, hi, BoxIndex.of(lo, hi))
        return self._index[2]

    def due(self, t: float) -> bool:
        """Whether a check is due at time ``t``."""
        return t - self._last_check >= self.settings.interval - 1e-9

    def check(
        self, t: float, x: np.ndarray, u: np.ndarray, followed: Followed, x_ref: np.ndarray
    ) -> tuple[str, float] | None:
        """(why, plan time now) when the state ``x`` at time ``t``, held one check interval under
        the control ``u``, would leave the tube (then braking must start now), else None."""
        loop = self.loop
        if not self.due(t):
            return None
        self._last_check = t
        x_now = np.asarray(x, dtype=float)
        x = loop.model.step(x_now, np.asarray(u, dtype=float), self.settings.interval)
        p = np.asarray(loop.model.position(x_now), dtype=float).ravel()
        p_ref = np.asarray(loop.model.position(x_ref), dtype=float).ravel()
        error = float(np.linalg.norm(p - p_ref))
        lo = loop.judged_lo if loop.judged_lo is not None else loop.problem.boxes_lo
        hi = loop.judged_hi if loop.judged_hi is not None else loop.problem.boxes_hi
        problem = followed.problem
        if self._views is None:  # frames come every 2-4 checks: stack them once per frame
            self._views = (
                np.array(self._R).reshape(-1, 3, 3),
                np.array(self._o).reshape(-1, 3),
            )
        R, o = self._views
        c, M = problem.family.ellipsoid(np.asarray(x, dtype=float))
        bounds = (problem.bounds_lo, problem.bounds_hi)
        start = problem.observed_start
        c, M = np.asarray(c, dtype=float).ravel(), np.asarray(M, dtype=float).reshape(3, 3)
        half = self._frame_faces(problem.frustum) if len(o) else None
        index = self._box_index(lo, hi)
        if ellipsoid_shown_safe(c, M, lo, hi, bounds, start, R, o, problem.frustum, half, index):
            self.quick += 1
            return None
        judged = dataclasses.replace(problem, boxes_lo=lo, boxes_hi=hi)
        margin, what = state_margin(x, judged, R, o)
        self.checks.append((t, margin))
        if margin >= -1e-6:
            return None
        why = (
            f"tracking guard: the state left the certified tube ({what}, margin {margin:+.3f} m,"
            f" {error:.3f} m from the plan)"
        )
        return why, t - followed.start
