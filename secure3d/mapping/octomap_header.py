"""Headers of OctoMap files, read first and bounded: what tree, how many nodes, what resolution.

Three headers exist (OctoMap 1.10, ``AbstractOcTree::readHeader``,
``AbstractOccupancyOcTree::readBinary`` and ``readBinaryLegacyHeader``):

- ``.bt``: ``# Octomap OcTree binary file`` then ``id``/``size``/``res`` lines and ``data``. The
  body holds only occupancy bits, so OctoMap's ``readBinary`` reads it whatever ``id`` the writer
  put there (``OcTree``, ``ColorOcTree``, ``OcTreeStamped``, a custom tree): so do we;
- legacy ``.bt`` (before the text header): ``int32 3`` (OcTree's old type number), ``float64 res``,
  ``uint32 size``, then the same body;
- ``.ot``: ``# Octomap OcTree file`` and the same lines. The body is each node's ``readData`` plus a
  child-mask byte, so its layout depends on ``id``: ``OcTree`` and ``OcTreeStamped`` store a
  ``float32`` log-odds (``OcTreeNodeStamped`` does not override ``readData``: timestamps are not in
  the file), ``ColorOcTree`` a ``float32`` log-odds then ``uint8`` r, g, b. OctoMap refuses ids it
  has no registered class for; we refuse every other id, in one line.

OctoMap requires an ``id`` line (``"Error reading OcTree header, ID not set"``) and maps the
deprecated ``id 1`` to ``OcTree``. Beyond OctoMap, a resolution outside
[:data:`MIN_RESOLUTION`, :data:`MAX_RESOLUTION`] is refused (OctoMap takes ``res 1e300``), and a file
is read header first: :func:`read_file_bounded` reads at most :data:`MAX_HEADER_BYTES`, validates
them, then only as many body bytes as the header's ``size`` allows (``/dev/zero`` is refused
after 4 KB).
"""

from __future__ import annotations

import math
import os
import struct
from pathlib import Path
from typing import NamedTuple

from secure3d.errors import MapFormatError

BT_MAGIC = b"# Octomap OcTree binary file"
OT_MAGIC = b"# Octomap OcTree file"
#: OctoMap's header is ~130 bytes; anything needing more than this is not a real header.
MAX_HEADER_BYTES = 4096
#: Resolutions (m) outside this range are unit errors or hostile (a 16-bit key at 1e-4 m spans
#: 6.5 m, at 100 m 6,500 km).
MIN_RESOLUTION = 1e-4
MAX_RESOLUTION = 100.0
#: Bytes per node in a ``.ot`` body (``readData`` + the child-mask byte), by tree id.
OT_NODE_BYTES = {"OcTree": 5, "OcTreeStamped": 5, "ColorOcTree": 8}
#: The legacy binary header: int32 tree type (3 = OcTree), float64 res, uint32 size.
_LEGACY = struct.Struct("<idI")
_LEGACY_TREE_TYPE = 3
#: Largest map file accepted by the readers (bytes).
MAX_FILE_BYTES = 1 << 30


_COMMENT = b"# (feel free to add / change comments, but leave the first line as it is!)\n#\n"


class Header(NamedTuple):
    """A validated OctoMap header.

    Attributes
    ----------
    fmt : {"bt", "ot"}
    tree_id : str
        The ``id`` line (``"OcTree"`` for a legacy ``.bt``).
    size : int
        Number of nodes, inner and leaves.
    resolution : float
    offset : int
        Index of the first body byte.
    legacy : bool
        The header is the pre-text binary one.
    """

    fmt: str
    tree_id: str
    size: int
    resolution: float
    offset: int
    legacy: bool = False

    def max_body_bytes(self) -> int:
        """Most body bytes a valid file with this header can have."""
        if self.fmt == "ot":
            return OT_NODE_BYTES[self.tree_id] * self.size
        return 2 * self.size  # one 2-byte record per inner node, fewer inner nodes than nodes


def check_resolution(res: float, text: str) -> float:
    """``res`` if finite and within [MIN_RESOLUTION, MAX_RESOLUTION]; else MapFormatError."""
    if not (math.isfinite(res) and res > 0.0):
        raise MapFormatError(f"bad header: res must be finite and > 0, got {text!r}")
    if not MIN_RESOLUTION <= res <= MAX_RESOLUTION:
        raise MapFormatError(
            f"bad header: res {text!r} is outside [{MIN_RESOLUTION:g}, {MAX_RESOLUTION:g}] m"
        )
    return res


def _text_fields(head: bytes) -> tuple[dict[str, str], int]:
    """The ``key value`` lines after the first, up to ``data``; and the first body byte."""
    fields: dict[str, str] = {}
    pos = head.find(b"\n")
    while True:
        nxt = head.find(b"\n", pos + 1) if pos >= 0 else -1
        if nxt < 0:
            raise MapFormatError(f"bad header: no 'data' line within {MAX_HEADER_BYTES} bytes")
        try:
            line = head[pos + 1 : nxt].decode("ascii")
        except UnicodeDecodeError:
            raise MapFormatError("bad header: non-ASCII bytes before the 'data' line") from None
        pos = nxt
        tokens = line.split()
        if not tokens or tokens[0].startswith("#"):
            continue
        if tokens[0] == "data":
            return fields, pos + 1
        if tokens[0] in ("id", "size", "res"):
            if len(tokens) != 2:
                raise MapFormatError(f"bad header line {line!r}: expected '{tokens[0]} <value>'")
            if tokens[0] in fields:
                raise MapFormatError(f"bad header: duplicate {tokens[0]!r} line")
            fields[tokens[0]] = tokens[1]
        # OctoMap skips unknown keywords with a warning; so do we.


def _text_header(head: bytes, fmt: str) -> Header:
    fields, offset = _text_fields(head)
    for name in ("id", "size", "res"):
        if name not in fields:
            raise MapFormatError(f"bad header: missing {name!r} line")
    tree_id = "OcTree" if fields["id"] == "1" else fields["id"]  # OctoMap's deprecated id
    if fmt == "ot" and tree_id not in OT_NODE_BYTES:
        raise MapFormatError(
            f"unsupported .ot tree type id {tree_id!r} (readable: {', '.join(OT_NODE_BYTES)})"
        )
    try:
        size = int(fields["size"])
    except ValueError:
        raise MapFormatError(f"bad header: size {fields['size']!r} is not an integer") from None
    if size < 0:
        raise MapFormatError(f"bad header: negative size {size}")
    try:
        res = float(fields["res"])
    except ValueError:
        raise MapFormatError(f"bad header: res {fields['res']!r} is not a number") from None
    return Header(fmt, tree_id, size, check_resolution(res, fields["res"]), offset)


def parse_header(data: bytes) -> Header:
    """Validate the header at the start of ``data`` (only its first MAX_HEADER_BYTES are read).

    Raises
    ------
    MapFormatError
        Not an OctoMap file, a missing or duplicate line, a ``.ot`` tree type without a known
        layout, a size that is not a non-negative integer, a resolution out of range.
    """
    head = bytes(data[:MAX_HEADER_BYTES])
    if head.startswith(BT_MAGIC):
        return _text_header(head, "bt")
    if head.startswith(OT_MAGIC):
        return _text_header(head, "ot")
    if len(head) >= _LEGACY.size and head[:4] == _LEGACY_TREE_TYPE.to_bytes(4, "little"):
        _, res, size = _LEGACY.unpack_from(head)
        return Header("bt", "OcTree", size, check_resolution(res, repr(res)), _LEGACY.size, True)
    raise MapFormatError(
        "bad header: not an OctoMap file (first line is neither "
        f"{BT_MAGIC.decode()!r} nor {OT_MAGIC.decode()!r}, nor a legacy binary header)"
    )


def read_file_bounded(path: str | os.PathLike[str], limit: int = MAX_FILE_BYTES) -> bytes:
    """Read an OctoMap file header first: never more than the header allows, nor ``limit``.

    Parameters
    ----------
    path : path
    limit : int
        Largest file accepted (bytes).

    Returns
    -------
    bytes
        The header and at most ``max_body_bytes() + 1`` body bytes (one more than valid, so the
        body parser reports trailing bytes).

    Raises
    ------
    MapFormatError
        A bad header, or more bytes than ``limit``.
    OSError
        The file cannot be opened or read.
    """
    p = Path(path)
    with p.open("rb") as fh:
        head = fh.read(MAX_HEADER_BYTES)
        header = parse_header(head)
        want = header.offset + header.max_body_bytes() + 1
        if want > limit + 1:
            raise MapFormatError(
                f"{p}: header's size {header.size} needs up to {want - 1} bytes, more than the"
                f" {limit}-byte limit"
            )
        rest = fh.read(max(0, want - len(head)))
    return head[:want] + rest


def _format_res(resolution: float) -> str:
    # OctoMap streams doubles with 6 significant digits; keep that when it is exact, else repr so
    # that our own files round-trip the resolution bit for bit.
    short = f"{resolution:.6g}"
    return short if float(short) == resolution else repr(float(resolution))


def format_header(magic: bytes, size: int, resolution: float, tree_id: str = "OcTree") -> bytes:
    """The text header OctoMap's ``writeBinary``/``write`` put before the body."""
    return (
        magic
        + b"\n"
        + _COMMENT
        + f"id {tree_id}\nsize {size}\nres {_format_res(resolution)}\ndata\n".encode()
    )
