"""An :class:`~secure3d.mapping.occupancy.OccupancyMap`'s sensor layer as OctoMap ``.bt``/``.ot``
files and buffers (byte-identical to OctoMap's; the claim layer is never written)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Self

import numpy as np
from numpy.typing import ArrayLike

from secure3d.errors import ConfigError, MapFormatError
from secure3d.mapping import octomap_io
from secure3d.mapping.sensor_model import OccupancyParams
from secure3d.outputs import atomic_write_bytes

__all__ = ["OccupancyFiles"]


class OccupancyFiles:
    """Reading and writing of :class:`~secure3d.mapping.occupancy.OccupancyMap` (a mixin: it reads
    the map's ``_sensor``, ``_params`` and ``_resolution``; the readers build the class they are
    called on)."""

    def to_bytes(self, fmt: str = "bt") -> bytes:
        """The sensor layer as an OctoMap ``.bt`` or ``.ot`` buffer.

        The tree is pruned as OctoMap keeps it while inserting (every group of 8 sibling leaves
        with equal log-odds merged); ``.bt`` then follows ``writeBinary`` (max-likelihood leaves,
        ``prune()``). For maps built by insertion, and for files OctoMap wrote, the output is
        byte-identical to OctoMap's ``writeBinary``/``write`` (tested). The claim layer is not
        written.

        Parameters
        ----------
        fmt : {"bt", "ot"}
        """
        starts, depths, vals = octomap_io.prune(*self._sensor.leaves())
        if fmt == "ot":
            return octomap_io.write_ot_bytes(self._resolution, starts, depths, vals)
        if fmt != "bt":
            raise ConfigError(f"fmt: expected 'bt' or 'ot', got {fmt!r}")
        p = self._params
        occ = vals >= p.threshold_log
        binary = np.where(occ, p.clamp_max_log, p.clamp_min_log).astype(np.float32)
        starts, depths, binary = octomap_io.prune(
            starts, depths, binary, stop_at_first_unpruned_level=True
        )
        return octomap_io.write_bt_bytes(
            self._resolution, starts, depths, binary >= p.threshold_log
        )

    @classmethod
    def from_bytes(
        cls,
        data: bytes,
        params: OccupancyParams = OccupancyParams(),  # noqa: B008 (frozen, immutable)
        bounds: tuple[ArrayLike, ArrayLike] | None = None,
    ) -> Self:
        """Map from a ``.bt`` or ``.ot`` buffer (recognised by its first line).

        ``.bt`` leaves get the clamping bounds of ``params`` as log-odds (OctoMap's reader does
        the same); ``.ot`` leaves keep their stored log-odds.

        Raises
        ------
        MapFormatError
            The buffer is not a valid OctoMap file (see
            :func:`secure3d.mapping.octomap_io.read_bt_bytes` and ``read_ot_bytes``).
        """
        if not isinstance(data, (bytes, bytearray, memoryview)):
            raise MapFormatError(f"expected bytes, got {type(data).__name__}")
        return cls._from_leaves(octomap_io.read_octomap_bytes(bytes(data)), params, bounds)

    @classmethod
    def _from_leaves(
        cls,
        leaves: octomap_io.Leaves,
        params: OccupancyParams,
        bounds: tuple[ArrayLike, ArrayLike] | None,
    ) -> Self:
        if leaves.fmt == "bt":
            values = np.where(leaves.values > 0, params.clamp_max_log, params.clamp_min_log)
        else:
            values = leaves.values
        out = cls(leaves.resolution, params, bounds)
        out._sensor.set_leaves(leaves.starts, leaves.depths, values.astype(np.float32))
        return out

    @classmethod
    def read_bt(
        cls,
        path: str | os.PathLike[str],
        params: OccupancyParams = OccupancyParams(),  # noqa: B008 (frozen, immutable)
        bounds: tuple[ArrayLike, ArrayLike] | None = None,
    ) -> Self:
        """Read an OctoMap ``.bt`` (or ``.ot``) file, header first; see :meth:`from_bytes`.

        Only the header (at most 4 KB) is read before it is validated, then only as many bytes as
        its ``size`` allows: ``read_bt("/dev/zero")`` fails after 4 KB.

        Raises
        ------
        MapFormatError
            Malformed, truncated or hostile content, or a file larger than ``MAX_FILE_BYTES``.
        OSError
            The file cannot be read.
        """
        return cls._from_leaves(octomap_io.read_octomap_file(Path(path)), params, bounds)

    read_ot = read_bt

    def write_bt(self, path: str | os.PathLike[str]) -> None:
        """Write the sensor layer as ``.bt`` atomically (temporary file, then ``os.replace``)."""
        atomic_write_bytes(path, self.to_bytes("bt"))

    def write_ot(self, path: str | os.PathLike[str]) -> None:
        """Write the sensor layer as ``.ot`` (log-odds kept) atomically."""
        atomic_write_bytes(path, self.to_bytes("ot"))
