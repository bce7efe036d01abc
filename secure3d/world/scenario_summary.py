"""The readable multi-line description of a scenario (``print(scenario)``, ``secure3d show``)."""

from __future__ import annotations

import math
import textwrap
from typing import TYPE_CHECKING

import numpy as np

from secure3d.world.spec_fields import (
    Vec3,
    _count,
    _fmt,
)

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.world.spec import Scenario


def scenario_summary(scenario: Scenario, max_obstacles: int = 30) -> str:
    """A readable multi-line description (also what ``secure3d show`` prints).

    Parameters
    ----------
    max_obstacles : int
        List at most this many obstacles one per line; the rest are counted.
    """
    w, b, v, c = scenario.world, scenario.world.bounds, scenario.vehicle, scenario.camera
    rows = _obstacle_rows(scenario)
    width = max([len(r[0]) for r in rows] + [4])
    kind_width = max([len(r[1]) for r in rows] + [3])
    out = [f"Scenario {scenario.name!r}" + (f"  ({scenario.source})" if scenario.source else "")]
    text = " ".join(scenario.description.split()) or "(no description)"
    out += textwrap.wrap(text, 96, initial_indent="  purpose   : ", subsequent_indent=" " * 14)
    ext = b.extent
    out.append(
        f"  world     : {ext[0]:g} x {ext[1]:g} x {ext[2]:g} m, bounds {_fmt(b.lo)} -"
        f" {_fmt(b.hi)}; {_count(len(w.boxes), 'box', 'boxes')},"
        f" {_count(len(w.meshes), 'mesh', 'meshes')}"
        + (f", octomap {w.octomap.name}" if w.octomap else "")
    )
    voxels = f", plus the occupied voxels of {w.octomap.name}" if w.octomap else ""
    out.append(f"  obstacles : {len(rows)} named (true and claimed){voxels}")
    for name, kind, lo, hi, note in rows[:max_obstacles]:
        line = f"    {name:<{width}}  {kind:<{kind_width}}  {_fmt(lo)} - {_fmt(hi)}"
        out.append(f"{line}  {note}" if note else line)
    if len(rows) > max_obstacles:
        out.append(f"    ... and {len(rows) - max_obstacles} more")
    s = scenario.server_map
    if not s.from_world:
        kind = "OctoMap" if s.bt else ("point cloud" if s.cloud else "mesh")
        claim = (
            f"given as its own {kind} {s.source_file.name}"
            if s.source_file is not None
            else f"a scan graph survey held in memory ({len(s.survey)} bytes)"
        )
        if s.attacks:
            claim += "; attacks: " + "; ".join(a.describe() for a in s.attacks)
    else:
        claim = "the truth with attacks: " + (
            "; ".join(a.describe() for a in s.attacks) if s.attacks else "none (honest)"
        )
    out.append(f"  server map: resolution {s.resolution:g} m, {claim}")
    lim = ", ".join(f"{k}={val:g}" for k, val in sorted(v.limits.items())) or "model defaults"
    out.append(f"  vehicle   : {v.model}, body radius {v.body_radius:g} m, limits: {lim}")
    vfov = math.degrees(c.vfov)
    out.append(
        f"  camera    : {c.width}x{c.height} px, hfov {c.hfov_deg:g} deg, vfov {vfov:.3g} deg,"
        f" {c.far_kind} limit {c.max_range:g} m, {c.rate_hz:g} Hz,"
        f" pitch {c.mount_pitch_deg:g} deg, offset {_fmt(c.mount_offset)} m"
        + (f", noise {c.noise_std:g} m" if c.noise_std else "")
        + (f", dropout {c.dropout:g}" if c.dropout else "")
    )
    out += _motion_lines(scenario)
    wrapped = [
        "\n".join(textwrap.wrap(line, 100, subsequent_indent=" " * 14)) if len(line) > 100 else line
        for line in out
    ]
    return "\n".join(wrapped)


def _obstacle_rows(scenario: Scenario) -> list[tuple[str, str, Vec3, Vec3, str]]:
    """(name, kind, lo, hi, note) of every true and claimed obstacle, with what the server did."""
    w = scenario.world
    status: dict[str, str] = {}
    for a in scenario.server_map.attacks:
        if a.target is None:
            continue
        if a.kind in ("hide", "stale"):
            status[a.target] = f"HIDDEN by the server ({a.kind})"
        elif a.kind == "shift":
            status[a.target] = f"SHIFTED by the server by {_fmt(a.offset)} m"
    for name in scenario.server_map.lacks:
        status.setdefault(name, "HIDDEN: the server's map lacks it")
    rows = [(o.name, "box", o.lo, o.hi, status.get(o.name, "")) for o in w.boxes]
    rows += [
        (
            o.name,
            f"mesh {o.path.name if o.path else '(inline)'}",
            o.lo,
            o.hi,
            status.get(o.name, ""),
        )
        for o in w.meshes
    ]
    rows += [
        (a.box.name, "box", a.box.lo, a.box.hi, "PHANTOM: claimed by the server, not real")
        for a in scenario.server_map.attacks
        if a.kind == "phantom" and a.box is not None
    ]
    return rows


def _motion_lines(scenario: Scenario) -> list[str]:
    """The start, goal, planner and simulation lines."""
    p, out = scenario.planner, []
    st, g = scenario.start, scenario.goal
    dist = float(np.linalg.norm(np.subtract(g.position, st.position)))
    out.append(
        f"  start     : {_fmt(st.position)} m, velocity {_fmt(st.velocity)} m/s,"
        f" yaw {math.degrees(st.yaw):.3g} deg"
    )
    out.append(
        f"  goal      : {_fmt(g.position)} m +- {g.tolerance:g} m"
        f" ({dist:.3g} m from the start in a straight line)"
    )
    look = f"{p.lookback} look-back" + (
        f" ({p.lookback_steps} steps)" if p.lookback == "fixed" else ""
    )
    out.append(
        f"  planner   : {p.nodes} nodes, {look}, {p.solver}, {p.reactive_family} reactive sets,"
        f" {p.controller} controller, margin {p.margin:g} m, max {p.max_iter} iterations"
    )
    sim = scenario.simulation
    out.append(f"  simulation: dt {sim.dt:g} s, time limit {sim.time_limit:g} s")
    return out
