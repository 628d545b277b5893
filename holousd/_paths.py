"""Output paths checked before any work starts, and OS errors turned into one-line messages.

Every command that writes checks its output path first (:func:`output_folder`, :func:`output_file`), so a bad
``--out`` is refused before anything is computed or written. :func:`describe_os_error` is what the CLI prints
for an ``OSError`` that still escapes (disk full mid-run, a folder made read-only while a stage ran).
"""

from __future__ import annotations

import errno
import os
import tempfile
from pathlib import Path

from holousd._errors import HolousdError

__all__ = ["describe_os_error", "output_file", "output_folder"]

_FIX = {
    errno.EACCES: "it is not writable: fix its permissions or choose another path",
    errno.EPERM: "it is not writable: fix its permissions or choose another path",
    errno.EROFS: "it is on a read-only file system: choose another path",
    errno.ENOSPC: "the disk is full: free some space and re-run",
    errno.EDQUOT: "the disk quota is exceeded: free some space and re-run",
    errno.ENOTDIR: "a part of the path is a file, not a folder: choose another path",
    errno.EEXIST: "a file of that name is in the way: remove it or choose another path",
    errno.EISDIR: "it is a folder, not a file: give a file name",
    errno.ENOENT: "it does not exist: check the path",
    errno.ENAMETOOLONG: "the path is too long: choose a shorter one",
}


def _reason(exc: OSError) -> str:
    reason = (exc.strerror or str(exc)).lower()
    return f"{reason}; {_FIX.get(exc.errno or 0, 'check the path, its permissions and the free disk space')}"


def describe_os_error(exc: OSError) -> str:
    """One line naming the file of an ``OSError`` and how to fix it."""
    name = exc.filename if exc.filename is not None else "<unknown file>"
    return f"{name}: {_reason(exc)}"


def _probe_writable(folder: Path, what: str) -> None:
    try:
        fd, probe = tempfile.mkstemp(prefix=".holousd-write-test.", dir=folder)
    except OSError as exc:
        raise HolousdError(f"{folder}: {what} cannot be written to ({_reason(exc)})") from exc
    os.close(fd)
    os.unlink(probe)


def output_folder(path: str | os.PathLike[str], what: str = "output folder", *, create: bool = True) -> Path:
    """Check (and create) a folder a command writes into; return it as an absolute path.

    Relative paths are taken from the current working folder, once, here: later stages may re-root paths
    beside the files they write, so an absolute path is what gets passed on.

    Args:
        path: The folder.
        what: What the folder is, for messages (``--out``, ``output folder``).
        create: Create it (False: only check that it could be created and written; nothing is made).

    Raises:
        HolousdError: the path is a file, lies under a file, cannot be created or is not writable.
    """
    folder = Path(path).absolute()
    if folder.exists() and not folder.is_dir():
        raise HolousdError(f"{folder}: {what} is an existing file; give a folder (or remove the file)")
    existing = folder
    for parent in folder.parents:
        if parent.exists():
            if not parent.is_dir():
                raise HolousdError(f"{folder}: {parent} is a file, not a folder; choose another {what}")
            existing = existing if existing.exists() else parent
            break
    if not create:
        _probe_writable(folder if folder.exists() else existing, what)
        return folder
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise HolousdError(f"{folder}: {what} cannot be created ({_reason(exc)})") from exc
    _probe_writable(folder, what)
    return folder


def output_file(path: str | os.PathLike[str], what: str = "output file", *, create: bool = True) -> Path:
    """Check a file a command writes (its folder is created unless ``create`` is False); return it as an
    absolute path.

    Raises:
        HolousdError: the path is a folder, its folder cannot be created or is not writable.
    """
    target = Path(path).absolute()
    if target.is_dir():
        raise HolousdError(f"{target}: {what} is an existing folder; give a file name")
    output_folder(target.parent, f"folder of the {what}", create=create)
    return target
