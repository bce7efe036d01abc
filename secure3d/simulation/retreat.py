"""Backing off a known obstacle the robot rests against (the ``RETREAT`` mode, beyond the paper).

Why. A robot brakes to rest inside its last certified reactive set, clear of the true obstacles,
but the map holds obstacles in whole voxels: the voxel that holds a surface reaches up to a voxel
towards the robot. So the body at rest can overlap a known obstacle box although it touches
nothing (a fence's top rail 0.19991 m from a body of radius 0.2 m; a scanned wall at 0.162 m).
The planner refuses such a start ("start is inside a known obstacle") and, before this mode, the
robot held still for the rest of the run. Here it first backs off, slowly and in a straight line,
until its body is clear of every known box by a few planner margins, then replans.

Why it is safe. The body at rest, the ball B(p0, r), is free: the robot is there. For a point p and
a set W, if every x in W is at least as near p0 as p (|x - p| >= |x - p0|: W lies wholly on p0's
side of the bisector plane of p0 and p), then whatever obstacle W holds is clear of B(p, r) because
it is clear of B(p0, r). The retreat lets the body reach p only where every voxel within ``r`` of p
that the camera has not seen free (unknown, claimed by the server, or occupied) meets that
condition; voxels the camera saw free are free by the trust the whole library puts in the camera
(and the start region observed before take-off, by the paper's premise). The condition is checked
in code at every control step, on the state the step will reach and on the braking manoeuvre from
there (:meth:`Retreat.control`): when it fails the robot brakes instead, along a manoeuvre checked
the step before.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from secure3d.errors import SimulationError

__all__ = [
    "RETREAT_MARGINS",
    "RETREAT_SPEED",
    "Retreat",
    "away_from",
    "bisector_clear",
    "plan_retreat",
    "unseen_voxels",
    "voxel_cells",
]

#: The retreat ends where the body is this many planner margins clear of every known box (the
#: first reactive sets of a plan from rest need one margin; the rest is room for tracking).
RETREAT_MARGINS = 3.0
#: Peak speed (m/s) of the retreat's reference (a minimum-jerk profile), and its shortest duration.
RETREAT_SPEED = 0.1
RETREAT_MIN_TIME = 1.0
#: Seconds the robot may lag its reference at the end before the retreat counts as done anyway.
RETREAT_SETTLE = 2.0
#: Sampling step (m) of the straight line when the retreat's length and path are chosen.
RETREAT_STEP = 0.002
#: How far (m) the body's centre may stray from the retreat's line (tracking error, braking).
RETREAT_SLACK = 0.05


def _points(a: object, what: str) -> np.ndarray:
    p = np.asarray(a, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or not np.all(np.isfinite(p)):
        raise SimulationError(f"{what}: expected finite (n, 3) points, got shape {np.shape(a)}")
    return p


def bisector_clear(
    points: np.ndarray, anchor: np.ndarray, radius: float, lo: np.ndarray, hi: np.ndarray
) -> np.ndarray:
    """(m,) bool: for each of ``points`` (m, 3), every box ``lo``, ``hi`` (n, 3) either lies at
    least ``radius`` from the point or wholly on ``anchor``'s side of the bisector plane of anchor
    and point (every x in it has |x - p| >= |x - anchor|).

    With the body at ``anchor`` known free, an obstacle inside a box of either kind is clear of the
    body at the point. The bisector test is exact for boxes: max over x in the box of
    (x - anchor).w, with w = p - anchor, is the box's support in w, and |x - p|^2 = |x - anchor|^2 -
    2 (x - anchor).w + |w|^2.
    """
    P = _points(points, "bisector_clear: points")
    lo, hi = _points(lo, "bisector_clear: lo"), _points(hi, "bisector_clear: hi")
    a = np.asarray(anchor, dtype=float).reshape(3)
    if not len(lo):
        return np.ones(len(P), dtype=bool)
    Q = P[:, None, :]
    far = np.linalg.norm(Q - np.clip(Q, lo, hi), axis=2) >= radius  # (m, n)
    w = Q - a  # (m, 1, 3)
    support = np.maximum(lo * w, hi * w).sum(axis=2) - (w * a).sum(axis=2)
    behind = support <= 0.5 * (w * w).sum(axis=2)
    return np.all(far | behind, axis=1)


def voxel_cells(lo: np.ndarray, hi: np.ndarray, res: float) -> np.ndarray:
    """(n, 3) int64 indices of the voxels of size ``res`` that meet the box ``lo``..``hi`` (3,)."""
    a = np.floor(np.asarray(lo, dtype=float) / res).astype(np.int64)
    b = np.floor(np.asarray(hi, dtype=float) / res).astype(np.int64)
    axes = [np.arange(a[d], b[d] + 1) for d in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def unseen_voxels(
    belief: object,
    centre: np.ndarray,
    reach: float,
    seen: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The voxels within the cube ``centre`` +- ``reach`` (m) that the camera has not seen free,
    as boxes (lo, hi) (n, 3): unknown, claimed free or occupied by the server, or occupied. Voxels
    wholly inside ``seen`` (lo, hi) (3,) count as seen free unless the map holds them occupied (the
    start region, observed before take-off)."""
    from secure3d.mapping.occupancy import Trust

    c = np.asarray(centre, dtype=float).reshape(3)
    if not (np.all(np.isfinite(c)) and np.isfinite(reach) and reach >= 0):
        raise SimulationError(f"unseen_voxels: need a finite centre and reach >= 0, got {reach!r}")
    res = float(belief.resolution)
    cells = voxel_cells(c - reach, c + reach, res)
    centres = (cells + 0.5) * res
    trust = np.asarray(belief.trust(centres))
    free = trust == Trust.SENSED_FREE
    if seen is not None:  # whole voxels only: a voxel's part outside the region was not seen
        inside = np.all((cells * res >= seen[0]) & ((cells + 1) * res <= seen[1]), axis=1)
        free |= inside & ~np.isin(trust, [Trust.CLAIMED_OCCUPIED, Trust.SENSED_OCCUPIED])
    kept = cells[~free]
    return kept * res, (kept + 1) * res


def away_from(
    position: np.ndarray, reach: float, lo: np.ndarray, hi: np.ndarray, planar: bool
) -> np.ndarray | None:
    """The unit direction (3,) away from the boxes ``lo``, ``hi`` (n, 3) that lie within ``reach``
    of ``position`` (3,): the sum of the unit vectors from each one's nearest point to the
    position (in the plane for a ``planar`` body), the way out of a corner as well as off a wall.
    None when no box is that near, or when the vectors cancel (the boxes surround it)."""
    p = np.asarray(position, dtype=float).reshape(3)
    if not len(lo):
        return None
    away = p[None, :] - np.clip(p[None, :], lo, hi)
    if planar:
        away[:, 2] = 0.0
    dist = np.linalg.norm(away, axis=1)
    near = (dist < reach) & (dist > 0.0)
    if not near.any():
        return None
    out = (away[near] / dist[near, None]).sum(axis=0)
    size = float(np.linalg.norm(out))
    return None if size < 1e-6 else out / size


@dataclass(frozen=True)
class Retreat:
    """A straight retreat from ``anchor`` (3,), where the body rests, along the unit ``direction``
    (3,) for ``length`` m, from simulation time ``start`` over ``duration`` s, at heading ``yaw``;
    ``unseen`` (lo, hi) (n, 3) are the voxels near it the camera has not seen free, and
    ``lo``, ``hi`` (3,) the box the body's centre must stay in (the map less the body radius)."""

    anchor: np.ndarray
    direction: np.ndarray
    length: float
    start: float
    duration: float
    yaw: float
    radius: float
    unseen: tuple[np.ndarray, np.ndarray]
    lo: np.ndarray
    hi: np.ndarray
    turn: bool = False  # turn on the spot to heading ``yaw`` first (then ``start`` is reset)

    @property
    def end(self) -> np.ndarray:
        return self.anchor + self.length * self.direction

    def safe(self, points: np.ndarray) -> bool:
        """Every one of ``points`` (m, 3) is a place the body may be (:meth:`refusal`)."""
        return self.refusal(points) is None

    def refusal(self, points: np.ndarray) -> str | None:
        """Why the body may not be at one of ``points`` (m, 3), or None: it must stay in the map,
        within RETREAT_SLACK of the line (``unseen`` holds the voxels near it only), and clear by
        the bisector test of every voxel not seen free (see the module)."""
        P = _points(points, "Retreat.refusal: points")
        if not np.all((P >= self.lo - 1e-9) & (P <= self.hi + 1e-9)):
            return "the body would leave the map"
        along = np.clip((P - self.anchor) @ self.direction, 0.0, self.length)
        off = float(np.linalg.norm(P - self.anchor - along[:, None] * self.direction, axis=1).max())
        if off > RETREAT_SLACK:
            return f"the body would stray {1e3 * off:.0f} mm from the line"
        ok = bisector_clear(P, self.anchor, self.radius, *self.unseen)
        if not ok.all():
            at = np.round(P[np.argmin(ok)], 3).tolist()
            return f"the body at {at} would reach space no view shows free"
        return None

    def reference(self, model: object, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The reference (x (nx,), u (nu,)) at simulation time ``t``: a minimum-jerk profile
        along the line, at rest at either end."""
        tau = float(np.clip((t - self.start) / self.duration, 0.0, 1.0))
        s = self.length * tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
        v = self.length * 30.0 * tau**2 * (1.0 - tau) ** 2 / self.duration
        x = model.initial_state(self.anchor + s * self.direction, v * self.direction, self.yaw)
        return x, model.nominal_control(x)

    def control(
        self, model: object, tracker: object, brake: object, x: np.ndarray, t: float, dt: float
    ) -> tuple[np.ndarray, str | None]:
        """The tracker's control towards the reference for the step from state ``x`` at time
        ``t``, and None, or why (:meth:`refusal`) the state it reaches in ``dt``, or the braking
        manoeuvre from there (``brake``'s roll-out), would put the body where it may not be."""
        x_ref, u_ref = self.reference(model, t + dt)
        u = np.asarray(tracker.control(x, x_ref, u_ref), dtype=float)
        x1 = np.asarray(model.step(x, u, dt), dtype=float)
        _, X = brake.rollout(x1, dt=dt, u_hold=u)
        P = np.asarray(model.position(np.vstack([x1[None], np.asarray(X).reshape(-1, len(x1))])))
        return u, self.refusal(P.reshape(-1, 3))

    def done(self, model: object, x: np.ndarray, t: float, stop_speed: float) -> bool:
        """The reference has ended and the robot is slower than ``stop_speed``, or it lagged
        RETREAT_SETTLE s past the end."""
        if t < self.start + self.duration:
            return False
        slow = float(np.linalg.norm(model.velocity(x))) < stop_speed
        return slow or t >= self.start + self.duration + RETREAT_SETTLE


def _first_clear(
    p0: np.ndarray, u: np.ndarray, radius: float, lo: np.ndarray, hi: np.ndarray, reach: float
) -> float | None:
    """The first length along ``u`` from ``p0`` (a multiple of RETREAT_STEP, at most ``reach``)
    where the ball of ``radius`` clears every box, or None."""
    ts = np.arange(1, int(np.ceil(reach / RETREAT_STEP)) + 1) * RETREAT_STEP
    P = p0[None, :] + ts[:, None] * u[None, :]
    Q = P[:, None, :]
    d = np.linalg.norm(Q - np.clip(Q, lo, hi), axis=2).min(axis=1)
    ok = np.flatnonzero(d >= radius)
    return None if not len(ok) else float(ts[ok[0]])


def _directions(model: object, x: np.ndarray, away: np.ndarray | None) -> list[np.ndarray]:
    """Unit directions (3,) a retreat may take: the way ``away`` from the boxes first (if any),
    then 16 directions in the plane (a planar body) or the 26 of the unit cube's faces, edges and
    corners; for a vehicle whose heading is its direction of motion, forwards and backwards along
    it first (no turn on the spot)."""
    if model.planar:
        a = np.arange(16) * (np.pi / 8.0)
        grid = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)
    else:
        g = np.stack(np.meshgrid(*[[-1.0, 0.0, 1.0]] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
        g = g[np.any(g != 0.0, axis=1)]
        grid = g / np.linalg.norm(g, axis=1, keepdims=True)
    first = [] if away is None else [away]
    if model.heading_follows_path:
        yaw = float(model.yaw(x))
        h = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        first = [h, -h] + first
    return first + list(grid)


def _facing(model: object, x: np.ndarray, u: np.ndarray) -> tuple[float, bool]:
    """(heading, turn first?) to retreat along ``u`` (3,): the current heading for a vehicle that
    can move any way; else the one of u's two headings (forwards, backwards) nearer the current."""
    yaw = float(model.yaw(x))
    if not model.heading_follows_path:
        return yaw, False
    ahead = float(np.arctan2(u[1], u[0]))
    back = float(np.arctan2(-u[1], -u[0]))
    err = [abs(float(np.angle(np.exp(1j * (a - yaw))))) for a in (ahead, back)]
    target = ahead if err[0] <= err[1] else back
    return target, min(err) > 1e-9


def plan_retreat(
    model: object,
    x: np.ndarray,
    t: float,
    boxes: tuple[np.ndarray, np.ndarray],
    margin: float,
    belief: object,
    bounds: tuple[np.ndarray, np.ndarray],
    seen: tuple[np.ndarray, np.ndarray] | None = None,
    within: float = 0.0,
) -> Retreat | None:
    """The shortest straight retreat (with no turn on the spot first if one will do) of a robot
    at rest in state ``x`` at time ``t`` whose body overlaps the known obstacle ``boxes`` (lo, hi)
    (n, 3), or comes ``within`` m of one, to RETREAT_MARGINS * ``margin`` clear of them, within a
    body radius plus a voxel and a half, through places :meth:`Retreat.safe` allows; None when
    the body is farther from them all or no direction (:func:`_directions`) has such a retreat.
    ``bounds`` (lo, hi) (3,) is the map's box, ``belief`` the robot's map, ``seen`` the start
    region observed before take-off."""
    r = float(model.body_radius)
    x = np.asarray(x, dtype=float)
    if x.shape != (model.nx,) or not np.all(np.isfinite(x)):
        raise SimulationError(f"plan_retreat: x must be {model.nx} finite numbers, got {x!r}")
    for name, v in (("margin", margin), ("within", within)):
        if not (np.isfinite(v) and v >= 0):
            raise SimulationError(f"plan_retreat: {name} must be a number >= 0 (m), got {v!r}")
    p0 = np.asarray(model.position(x), dtype=float).reshape(3)
    lo, hi = (np.asarray(b, dtype=float).reshape(-1, 3) for b in boxes)
    clear = RETREAT_MARGINS * float(margin)
    reach = r + clear + 1.5 * float(belief.resolution)
    near = np.linalg.norm(p0 - np.clip(p0, lo, hi), axis=1) < r + reach + clear
    lo, hi = lo[near], hi[near]
    if not len(lo) or np.linalg.norm(p0 - np.clip(p0, lo, hi), axis=1).min() >= r + within:
        return None
    away = away_from(p0, r + float(margin), lo, hi, bool(model.planar))
    options = []
    for u in _directions(model, x, away):
        length = _first_clear(p0, u, r + clear, lo, hi, reach)
        if length is not None:
            options.append((_facing(model, x, u)[1], length, len(options), u))
    if not options:
        return None
    ulo, uhi = unseen_voxels(belief, p0, reach + r + RETREAT_SLACK, seen)
    box = (np.asarray(bounds[0], dtype=float) + r, np.asarray(bounds[1], dtype=float) - r)
    # no turn on the spot first where one will do, then the shortest
    for _, length, _, u in sorted(options, key=lambda o: o[:3]):
        # the voxels within a body radius of anywhere the centre may be: the line and its slack
        keep = _near_segment(ulo, uhi, (p0, p0 + length * u), r + RETREAT_SLACK)
        duration = max(RETREAT_MIN_TIME, 1.875 * length / RETREAT_SPEED)
        yaw, turn = _facing(model, x, u)
        unseen = (ulo[keep], uhi[keep])
        retreat = Retreat(p0, u, length, t, duration, yaw, r, unseen, *box, turn)
        n = int(np.ceil(length / RETREAT_STEP)) + 1
        if retreat.safe(p0[None, :] + np.linspace(0.0, length, n)[:, None] * u[None, :]):
            return retreat
    return None


def _near_segment(
    lo: np.ndarray, hi: np.ndarray, ends: tuple[np.ndarray, np.ndarray], reach: float
) -> np.ndarray:
    """(n,) bool: the boxes ``lo``, ``hi`` (n, 3) within ``reach`` of the segment ``ends``,
    conservatively (their centres within reach plus half their diagonal)."""
    a, b = ends
    c = 0.5 * (lo + hi)
    d = b - a
    s = np.clip(((c - a) @ d) / max(float(d @ d), 1e-300), 0.0, 1.0)
    gap = np.linalg.norm(c - a - s[:, None] * d, axis=1)
    return gap <= reach + 0.5 * np.linalg.norm(hi - lo, axis=1)
