"""The scenarios shipped with secure3d, found by name.

The repository's ``maps/`` folder is shipped inside the package as ``secure3d/maps`` (a link in a
source checkout, a real folder in the installed wheel), so ``load_scenario("blind_corner")`` and
``secure3d demo`` work from any directory, with or without a checkout.
"""

from __future__ import annotations

import os
import re
from importlib import resources
from pathlib import Path

from secure3d.errors import ScenarioError

__all__ = ["bundled_dir", "bundled_names", "resolve_scenario"]

_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")


def bundled_dir() -> Path:
    """The folder of the shipped scenarios (``secure3d/maps``)."""
    return Path(str(resources.files("secure3d") / "maps"))


def bundled_names() -> tuple[str, ...]:
    """The names of the shipped scenarios, sorted (``("beam_3d", "blind_corner", ...)``)."""
    folder = bundled_dir()
    if not folder.is_dir():
        return ()
    return tuple(sorted(p.stem for p in folder.glob("*.yaml")))


def resolve_scenario(path_or_name: str | os.PathLike[str]) -> Path:
    """A scenario file for ``path_or_name``: the path itself when it exists, else the shipped
    scenario of that name (``"blind_corner"`` or ``"blind_corner.yaml"``).

    A missing path that is not a bare name is returned unchanged, so the reader reports it as
    "no such file". An unknown bare name raises :class:`ScenarioError` listing the shipped names.
    """
    text = os.fspath(path_or_name)
    path = Path(text)
    if path.exists() or not _NAME.fullmatch(text):
        return path
    stem = text[: -len(".yaml")] if text.endswith(".yaml") else text
    if stem in bundled_names():
        return bundled_dir() / f"{stem}.yaml"
    if path.suffix and path.suffix != ".yaml":
        return path
    known = ", ".join(bundled_names()) or "none"
    raise ScenarioError(
        f"{text}: no such file, and no shipped scenario of that name (shipped: {known})"
    )
