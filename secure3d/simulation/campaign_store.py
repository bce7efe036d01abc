"""A campaign's folder on disk: the append-only ``runs.csv``, resume, merge, and failure files.

``OUT/runs.csv`` is the campaign's record of truth:

- line 1 is a comment, ``# secure3d campaign {json}``: the campaign's parameters
  (:func:`campaign_params`: base scenario and its hash, n, seed, planners, variant kind, planner
  options, shard) and the library version;
- line 2 is the CSV header (:data:`RUNS_FIELDS`: today's :data:`~secure3d.simulation.campaign.
  CSV_FIELDS` plus ``solve_times``, so statistics can be recomputed exactly from the file);
- then one row per finished run, appended and flushed as the run finishes: O(1) per row, whatever
  the number of rows already written.

A run killed mid-write leaves at most a partial last line; :func:`open_runs` cuts it off before
appending, so ``--resume`` sees only whole rows. :func:`merge_campaigns` combines the folders of
the shards of one campaign and recomputes the statistics.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import io
import json
import math
import os
import shutil
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from secure3d import outputs
from secure3d.errors import ConfigError, Secure3DError
from secure3d.simulation.campaign_records import (
    CERTIFY_FIELDS,
    CSV_FIELDS,
    CSV_NAME,
    SUMMARY_NAME,
    CampaignResult,
    RunRecord,
    _csv_text,
)

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.world.spec import Scenario

__all__ = [
    "FAILURES_DIR",
    "RUNS_FIELDS",
    "RUNS_NAME",
    "RunsFile",
    "campaign_params",
    "merge_campaigns",
    "open_runs",
    "read_runs",
    "record_from_row",
    "save_failure",
    "write_reports",
]

RUNS_NAME = "runs.csv"
FAILURES_DIR = "failures"
#: Columns of ``runs.csv``: those of ``campaign.csv`` and every solve time of the run (s).
RUNS_FIELDS = (*CSV_FIELDS, "solve_times")
#: The columns before issue 16's certificate counts (still read; the counts read as 0).
_LEGACY_RUNS_FIELDS = tuple(f for f in RUNS_FIELDS if f not in CERTIFY_FIELDS)
#: Start of ``runs.csv``'s first line, followed by the parameters as JSON.
HEADER_PREFIX = "# secure3d campaign "
#: Format of ``runs.csv`` (raised when its columns or header change meaning).
FORMAT = 1
#: Parameters that may differ between the shards of one campaign (everything else must match).
SHARD_KEYS = ("shard",)


def scenario_digest(scenario: Scenario) -> str:
    """SHA-256 (16 hex digits) of the scenario's plain data: two bases with the same digest fly
    the same variants."""
    from secure3d.world.scenario import scenario_to_dict

    try:
        data: object = scenario_to_dict(scenario)
    except Secure3DError:  # a file reference outside its folder: hash what we have
        data = repr(scenario)
    text = json.dumps(data, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def campaign_params(
    base: Scenario,
    n: int,
    seed: int,
    planners: Sequence[str],
    kind: str,
    count: int,
    options: Mapping[str, object],
    replan_defer: float,
    shard: tuple[int, int],
) -> dict[str, Any]:
    """The parameters that fix a campaign's runs (``--resume`` refuses when they differ)."""
    return {
        "format": FORMAT,
        "base": base.name,
        "base_sha256": scenario_digest(base),
        "n": n,
        "seed": seed,
        "planners": list(planners),
        "kind": kind,
        "count": count,
        "options": {k: options[k] for k in sorted(options)},
        "replan_defer": replan_defer,
        "shard": list(shard),
    }


def _header_line(params: Mapping[str, Any]) -> str:
    from secure3d import __version__

    data = {**params, "secure3d_version": __version__}
    return HEADER_PREFIX + json.dumps(data, sort_keys=True) + "\n"


def _row_values(record: RunRecord) -> list[str]:
    row = record.row()
    times = " ".join(f"{t:.6g}" for t in record.solve_times)
    return [row[k] for k in CSV_FIELDS] + [times]


class RunsFile:
    """``runs.csv`` open for appending: :meth:`append` writes one row and flushes it."""

    def __init__(self, path: Path, handle: IO[str]) -> None:
        self.path = path
        self._handle = handle
        self._writer = csv.writer(handle, lineterminator="\n")

    def append(self, record: RunRecord) -> None:
        """Write ``record`` as one line and hand it to the OS (a crash after this loses nothing)."""
        self._writer.writerow(_row_values(record))
        self._handle.flush()

    def close(self) -> None:
        """Close the file (idempotent)."""
        self._handle.close()

    def __enter__(self) -> RunsFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _cut_partial_line(path: Path) -> None:
    """Drop a last line without its newline (a write cut short by a kill)."""
    with open(path, "rb+") as fh:
        fh.seek(0, os.SEEK_END)
        size = fh.tell()
        if size == 0:
            return
        fh.seek(max(0, size - 65536))
        tail = fh.read()
        if tail.endswith(b"\n"):
            return
        cut = tail.rfind(b"\n")
        fh.truncate(size - len(tail) + cut + 1 if cut >= 0 else 0)


def open_runs(
    out: Path, params: Mapping[str, Any], resume: bool
) -> tuple[RunsFile, list[RunRecord]]:
    """Open ``OUT/runs.csv`` for this campaign and return it with the runs it already holds.

    Without ``resume`` an existing ``runs.csv`` is refused (one line), so no run is ever lost;
    with it, the file's parameters must equal ``params`` (the library version may differ).

    Raises
    ------
    ConfigError
        ``runs.csv`` exists without ``resume``, or its parameters differ (each difference named).
    """
    path = out / RUNS_NAME
    if path.exists() and path.stat().st_size > 0:
        if not resume:
            raise ConfigError(
                f"{path} exists: pass --resume to continue that campaign, or choose another --out"
            )
        _cut_partial_line(path)
        old, records = read_runs(path)
        _check_same(old, params, path)
        return RunsFile(path, open(path, "a", newline="", encoding="utf-8")), records
    handle = open(path, "w", newline="", encoding="utf-8")
    handle.write(_header_line(params))
    csv.writer(handle, lineterminator="\n").writerow(RUNS_FIELDS)
    handle.flush()
    return RunsFile(path, handle), []


def _differences(old: Mapping[str, Any], new: Mapping[str, Any], skip: Iterable[str]) -> list[str]:
    keys = (set(old) | set(new)) - {"secure3d_version", "merged_from", *skip}
    return [
        f"{k} {old.get(k)!r} there, {new.get(k)!r} here"
        for k in sorted(keys)
        if _canonical(old.get(k)) != _canonical(new.get(k))
    ]


def _canonical(value: object) -> str:
    return json.dumps(value, sort_keys=True, default=str)


def _check_same(old: Mapping[str, Any], new: Mapping[str, Any], path: Path) -> None:
    diff = _differences(old, new, ())
    if diff:
        raise ConfigError(
            f"--resume: {path} holds another campaign ({'; '.join(diff)}); use the same"
            " parameters or another --out"
        )


def read_runs(path: str | os.PathLike[str]) -> tuple[dict[str, Any], list[RunRecord]]:
    """The parameters and the runs of a ``runs.csv`` (a partial last line is ignored).

    Raises
    ------
    ConfigError
        The file is missing or is not a campaign's ``runs.csv``.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file (not a campaign folder?)") from None
    first, _, rest = text.partition("\n")
    if not first.startswith(HEADER_PREFIX):
        raise ConfigError(f"{path}: not a secure3d campaign's runs.csv (no parameter line)")
    try:
        params = json.loads(first[len(HEADER_PREFIX) :])
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{path}: bad parameter line: {exc}") from None
    if not rest.endswith("\n"):
        rest = rest[: rest.rfind("\n") + 1]
    reader = csv.DictReader(io.StringIO(rest))
    if tuple(reader.fieldnames or ()) not in (RUNS_FIELDS, _LEGACY_RUNS_FIELDS):
        raise ConfigError(f"{path}: unexpected columns {reader.fieldnames}")
    return params, [record_from_row(row) for row in reader]


def _float(text: str) -> float:
    return float(text) if text else math.nan


def record_from_row(row: Mapping[str, str]) -> RunRecord:
    """The :class:`RunRecord` of a ``runs.csv`` row (numbers as written: 6 significant digits)."""
    return RunRecord(
        variant=int(row["variant"]),
        scenario=row["scenario"],
        seed=int(row["seed"]),
        planner=row["planner"],
        outcome=row["outcome"],
        collided=row["collided"] == "1",
        reached_goal=row["reached_goal"] == "1",
        time_to_goal=_float(row["time_to_goal"]),
        min_clearance=_float(row["min_clearance"]),
        takeovers=int(row["takeovers"]),
        replans=int(row["replans"]),
        solve_times=tuple(float(t) for t in row["solve_times"].split()),
        sim_time=_float(row["sim_time"]) if row["sim_time"] else 0.0,
        wall_time=_float(row["wall_time"]) if row["wall_time"] else 0.0,
        setup_time=_float(row["setup_time"]) if row["setup_time"] else 0.0,
        detection_time=_float(row["detection_time"]),
        plans_judged=int(row.get("plans_judged") or 0),
        certified_first_try=int(row.get("certified_first_try") or 0),
        error=row["error"],
    )


def sort_records(records: Iterable[RunRecord], planners: Sequence[str]) -> list[RunRecord]:
    """Variant-major, planners in campaign order (the order of ``campaign.csv``)."""
    order = {p: k for k, p in enumerate(planners)}
    return sorted(records, key=lambda r: (r.variant, order.get(r.planner, len(order))))


def settings_of(params: Mapping[str, Any], workers: object) -> dict[str, object]:
    """The report settings (:attr:`CampaignResult.settings`) of a campaign's parameters."""
    return {
        "kind": params["kind"],
        "count": params["count"],
        "workers": workers,
        "options": dict(params["options"]),
        "replan_defer": params["replan_defer"],
        "shard": tuple(params["shard"]) if params.get("shard") else None,
    }


def write_reports(out: Path, result: CampaignResult) -> None:
    """Write ``campaign.csv`` (sorted rows) and ``summary.md`` atomically."""
    outputs.atomic_write_text(out / CSV_NAME, _csv_text(result.records))
    outputs.atomic_write_text(out / SUMMARY_NAME, result.summary_markdown())


# ---- merge -------------------------------------------------------------------------------------


def merge_campaigns(
    folders: Sequence[str | os.PathLike[str]], out_dir: str | os.PathLike[str]
) -> CampaignResult:
    """Combine the folders of one campaign's shards (or resumed parts) into ``out_dir``.

    The parameters of every ``runs.csv`` must match except the shard; a (variant, planner) pair
    present twice is refused. ``out_dir`` gets ``runs.csv`` (the union, header ``shard`` null and
    ``merged_from`` listing the folders), ``campaign.csv``, ``summary.md`` with the statistics
    recomputed over every run, and the shards' ``failures/`` files.

    Raises
    ------
    ConfigError
        No folder, a folder without ``runs.csv``, parameters that differ, or a repeated run.
    """
    if not folders:
        raise ConfigError("campaign-merge: give at least one campaign folder")
    parts = [(Path(f), *read_runs(Path(f) / RUNS_NAME)) for f in folders]
    params0 = parts[0][1]
    seen: dict[tuple[int, str], Path] = {}
    records: list[RunRecord] = []
    for folder, params, recs in parts:
        diff = _differences(params0, params, SHARD_KEYS)
        if diff:
            raise ConfigError(
                f"campaign-merge: {folder} is another campaign than {parts[0][0]}: {'; '.join(diff)}"
            )
        for r in recs:
            key = (r.variant, r.planner)
            if key in seen:
                raise ConfigError(
                    f"campaign-merge: variant {r.variant} / {r.planner} is in both {seen[key]}"
                    f" and {folder}"
                )
            seen[key] = folder
            records.append(r)
    out = Path(out_dir)
    _make_dir(out)
    params = {**params0, "shard": None, "merged_from": [str(f) for f, _, _ in parts]}
    records = sort_records(records, params["planners"])
    text = io.StringIO()
    text.write(_header_line(params))
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(RUNS_FIELDS)
    writer.writerows(_row_values(r) for r in records)
    outputs.atomic_write_text(out / RUNS_NAME, text.getvalue())
    for folder, _, _ in parts:
        _copy_failures(folder / FAILURES_DIR, out / FAILURES_DIR)
    result = CampaignResult(
        base=params["base"],
        n=params["n"],
        planners=tuple(params["planners"]),
        seed=params["seed"],
        records=tuple(records),
        csv_path=out / CSV_NAME,
        summary_path=out / SUMMARY_NAME,
        wall_time=sum(r.wall_time for r in records),
        settings={**settings_of(params, "-"), "merged": len(parts)},
    )
    write_reports(out, result)
    return result


def _make_dir(folder: Path) -> None:
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"cannot create {str(folder)!r}: {exc.strerror or exc}") from None


def _copy_failures(src: Path, dst: Path) -> None:
    if not src.is_dir() or src.resolve() == dst.resolve():
        return
    shutil.copytree(src, dst, dirs_exist_ok=True)


# ---- failures ----------------------------------------------------------------------------------

#: File references of the scenario schema: (section, key).
_FILE_KEYS = (
    ("world", "octomap"),
    ("server_map", "octomap"),
    ("server_map", "cloud"),
    ("server_map", "mesh"),
)


def _failure_data(scenario: Scenario, folder: Path) -> dict[str, Any]:
    """The scenario's plain data with every referenced file copied under ``folder/assets``."""
    from secure3d.world.scenario import scenario_to_dict

    source = scenario.source.parent if scenario.source is not None else folder
    data = scenario_to_dict(scenario, source)

    def local(rel: str) -> str:
        src = (source / rel).resolve()
        digest = hashlib.sha256(str(src).encode()).hexdigest()[:8]
        dst = folder / "assets" / f"{digest}_{src.name}"
        if not dst.exists():
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(src, dst)
        return f"assets/{dst.name}"

    for mesh in data["world"]["meshes"]:
        if "file" in mesh:
            mesh["file"] = local(mesh["file"])
    for section, key in _FILE_KEYS:
        if data[section].get(key):
            data[section][key] = local(data[section][key])
    survey = scenario.server_map.survey
    if survey is not None:  # a family's survey held in memory: written as a .graph asset
        dst = folder / "assets" / f"{hashlib.sha256(survey).hexdigest()[:8]}_survey.graph"
        dst.parent.mkdir(parents=True, exist_ok=True)
        dst.write_bytes(survey)
        del data["server_map"]["survey"]
        data["server_map"]["cloud"] = f"assets/{dst.name}"
    return data


#: Second line of a failure file, before its ``simulate`` options.
_FLY_AGAIN = "# Fly it again: secure3d simulate "


def failure_defaults(path: str | os.PathLike[str]) -> dict[str, str]:
    """The ``simulate`` options a failure file names (``planner``, ``seed``, ``replan_defer``);
    empty for any other scenario file."""
    try:
        with open(path, encoding="utf-8") as fh:
            lines = [fh.readline(), fh.readline()]
    except (OSError, UnicodeDecodeError):
        return {}
    if not lines[0].startswith("# Campaign failure:") or not lines[1].startswith(_FLY_AGAIN):
        return {}
    words = lines[1][len(_FLY_AGAIN) :].split()[1:]
    pairs = zip(words[::2], words[1::2], strict=False)
    return {k[2:].replace("-", "_"): v for k, v in pairs if k.startswith("--")}


def save_failure(
    out: Path,
    scenario: Scenario,
    record: RunRecord,
    options: Mapping[str, object],
    replan_defer: float,
) -> Path:
    """Write ``OUT/failures/<variant>_<planner>.yaml``: the variant's scenario with the campaign's
    planner options in its ``planner`` section, and a comment giving the command that flies the run
    again (planner, seed and replan deferral are not part of a scenario; ``secure3d simulate FILE``
    reads them from it, :func:`failure_defaults`)."""
    import yaml

    from secure3d.world.spec import PlannerSpec

    folder = out / FAILURES_DIR
    folder.mkdir(parents=True, exist_ok=True)
    spec_fields = {f.name for f in dataclasses.fields(PlannerSpec)}
    baked = {k: v for k, v in options.items() if k in spec_fields}
    if baked:
        scenario = dataclasses.replace(
            scenario, planner=dataclasses.replace(scenario.planner, **baked)
        )
    path = folder / f"{record.variant:06d}_{record.planner}.yaml"
    data = _failure_data(scenario, folder)
    extra = "".join(
        f" --{k.replace('_', '-')} {v}" for k, v in options.items() if k not in spec_fields
    )
    lines = [
        f"# Campaign failure: variant {record.variant}, planner {record.planner}, outcome"
        f" {record.outcome}{': ' + record.error if record.error else ''}",
        f"{_FLY_AGAIN}{path.name} --planner {record.planner}"
        f" --seed {record.seed} --replan-defer {replan_defer:g}{extra}",
    ]
    text = "\n".join(" ".join(line.split()) for line in lines) + "\n"
    text += yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=100)
    outputs.atomic_write_text(path, text)
    return path
