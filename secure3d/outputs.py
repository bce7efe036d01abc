"""The output contract: every file secure3d writes is checked before the work and written atomically.

- :func:`check_output_path` runs before a flight, a campaign or a figure is computed: the folder
  exists or is created, the path is not a directory, its extension is one the writer makes, and
  the folder really accepts a file (a probe file is created and removed, which also catches
  read-only mounts and ``/sys``). Its error is one line, :class:`~secure3d.errors.OutputError`.
- :func:`temporary_path` names a unique temporary file in the target folder (``.<name>.<pid>.
  <random>.part``, ignored by git), so two runs writing the same path never share one; the writer
  renames it over the target (:func:`os.replace`, atomic on one file system) or removes it.
- :func:`atomic_output` is the one writer: it opens the temporary file, yields it, and renames it
  over the target when the block ends normally, or removes it on any exception (Ctrl-C included).
  :func:`atomic_write_bytes` and :func:`atomic_write_text` use it for whole files; figures, map
  files and campaign tables use it too. Rerun's recordings stream into a :func:`temporary_path`
  of their own and end the same way, through :func:`commit_temporary` or :func:`discard_temporary`.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import threading
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import BinaryIO

from secure3d.errors import OutputError

__all__ = [
    "atomic_output",
    "atomic_write_bytes",
    "atomic_write_text",
    "check_output_path",
    "commit_temporary",
    "discard_temporary",
    "release_temporary",
    "remove_temporaries",
    "temporary_path",
]

#: Temporary files handed out by :func:`temporary_path` and not yet renamed or removed: what
#: :func:`remove_temporaries` deletes when the process must stop at once (a second Ctrl-C).
_live: set[Path] = set()
_live_lock = threading.Lock()


def check_output_path(
    path: str | os.PathLike[str], suffixes: Iterable[str], what: str = "output"
) -> Path:
    """Check that ``path`` can be written, before any work; return it as an absolute Path.

    Parameters
    ----------
    path : the file to write.
    suffixes : accepted extensions, lower case with the dot (``(".png",)``).
    what : the option or field name for the message (``"--png"``, ``"rrd"``).

    Raises
    ------
    OutputError
        ``path`` is a directory, has another extension, or its folder cannot be created or
        written.
    """
    allowed = tuple(s.lower() for s in suffixes)
    p = Path(os.fspath(path)).expanduser()
    if str(path).endswith(("/", os.sep)) or p.is_dir():
        raise OutputError(
            f"{what}: {str(path)!r} is a directory; give a file name ending in {allowed[0]}"
        )
    if p.suffix.lower() not in allowed:
        raise OutputError(f"{what}: {str(path)!r} must end in {' or '.join(allowed)}")
    folder = p.resolve().parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(
            f"{what}: cannot create folder {str(folder)!r}: {exc.strerror or exc}"
        ) from None
    probe = temporary_path(p.resolve())
    try:
        probe.touch(exist_ok=False)
        probe.unlink()
    except OSError as exc:
        raise OutputError(
            f"{what}: cannot write in {str(folder)!r}: {exc.strerror or exc}"
        ) from None
    finally:
        release_temporary(probe)
    if p.exists() and not os.access(p, os.W_OK):
        raise OutputError(f"{what}: {str(p)!r} exists and is not writable")
    return p.resolve()


def temporary_path(path: str | os.PathLike[str]) -> Path:
    """A unique temporary file name beside ``path``: ``.<name>.<pid>.<random>.part``.

    The name is registered until :func:`release_temporary`, so that :func:`remove_temporaries`
    can delete it if the process has to stop before its writer finishes."""
    p = Path(path)
    tmp = p.with_name(f".{p.name}.{os.getpid()}.{secrets.token_hex(4)}.part")
    with _live_lock:
        _live.add(tmp.absolute())
    return tmp


def release_temporary(tmp: str | os.PathLike[str]) -> None:
    """Forget a temporary name of :func:`temporary_path` (renamed into place or removed)."""
    with _live_lock:
        _live.discard(Path(tmp).absolute())


def remove_temporaries() -> list[Path]:
    """Delete every temporary file still registered (for an immediate exit); return them."""
    with _live_lock:
        live = list(_live)
        _live.clear()
    removed = []
    for tmp in live:
        with contextlib.suppress(OSError):
            tmp.unlink()
            removed.append(tmp)
    return removed


def commit_temporary(tmp: str | os.PathLike[str], path: str | os.PathLike[str]) -> Path:
    """Rename a finished temporary file of :func:`temporary_path` over ``path`` (atomic on one
    file system) and forget it; returns ``path``."""
    os.replace(tmp, path)
    release_temporary(tmp)
    return Path(path)


def discard_temporary(tmp: str | os.PathLike[str]) -> None:
    """Remove a temporary file of :func:`temporary_path` (if it exists) and forget it."""
    with contextlib.suppress(FileNotFoundError):
        Path(tmp).unlink()
    release_temporary(tmp)


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike[str], mode: int = 0o666) -> Iterator[BinaryIO]:
    """Open a unique temporary file beside ``path`` for binary writing; on a normal exit of the
    block, flush it to disk and rename it over ``path``; on any exception, remove it.

    ``mode`` is masked by the umask, as for any new file (``mkstemp``'s 0600 is not).
    """
    p = Path(path)
    tmp = temporary_path(p)
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
        with os.fdopen(fd, "wb") as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        commit_temporary(tmp, p)
    except BaseException:
        discard_temporary(tmp)
        raise


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes, mode: int = 0o666) -> Path:
    """Write ``data`` to ``path`` through :func:`atomic_output`."""
    with atomic_output(path, mode) as fh:
        fh.write(data)
    return Path(path)


def atomic_write_text(path: str | os.PathLike[str], text: str) -> Path:
    """:func:`atomic_write_bytes` of UTF-8 text."""
    if not isinstance(text, str):
        raise TypeError(f"atomic_write_text: text must be str, got {type(text).__name__}")
    return atomic_write_bytes(path, text.encode("utf-8"))
