"""Atomic file writes: write to a temporary file beside the target, then rename over it.

A crash, Ctrl-C or error while writing never leaves a half-written file and never destroys the file that was
there before.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

__all__ = ["atomic_path", "folder_transaction"]


@contextlib.contextmanager
def atomic_path(target: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``target``; on success rename it over ``target``.

    The temporary file keeps ``target``'s suffix so that format-by-extension writers (USD layers, numpy, PNG)
    pick the right format. On any exception the temporary file is removed and ``target`` is left untouched.

    Args:
        target: Final path of the file.

    Yields:
        The temporary path to write to.
    """
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.stem}.", suffix=f".tmp{target.suffix}", dir=target.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        if target.exists():
            mode = target.stat().st_mode & 0o777
        else:
            umask = os.umask(0)
            os.umask(umask)
            mode = 0o666 & ~umask
        os.chmod(tmp, mode)
        os.replace(tmp, target)
    finally:
        if tmp.exists():
            tmp.unlink()


@contextlib.contextmanager
def folder_transaction(folder: str | os.PathLike[str], patterns: tuple[str, ...]) -> Iterator[None]:
    """Undo every change to the files of ``folder`` that match ``patterns`` when the body fails.

    Before the body runs, each matching file is copied into a hidden folder inside ``folder`` (symbolic links are
    recorded as links). When the body raises (any exception, Ctrl-C included), files it created are removed,
    files it replaced or deleted are moved back from the copies (a rename: byte for byte, modification times
    kept, no free space needed), links are re-made, and folders it created are removed; then the exception goes
    on. On success the copies are dropped. Should putting a file back fail, the copies are kept and the error
    names their folder. This is what lets a multi-stage command promise that a failure leaves its output folder
    as it was.

    Args:
        folder: The folder (it must exist).
        patterns: ``Path.glob`` patterns relative to ``folder`` (``"*.usda"``, ``"assets/**/*"``).
    """
    import shutil

    from holousd._errors import HolousdError

    folder = Path(folder)

    def matching() -> tuple[set[Path], dict[Path, str], set[Path]]:
        files, links, dirs = set(), {}, set()
        for pattern in patterns:
            for p in folder.glob(pattern):
                if p.is_symlink():
                    links[p] = os.readlink(p)
                elif p.is_file():
                    files.add(p)
                elif p.is_dir():
                    dirs.add(p)
        return files, links, dirs

    before_files, before_links, before_dirs = matching()
    backup = Path(tempfile.mkdtemp(prefix=".holousd-undo.", dir=folder))
    keep_backup = False
    try:
        for path in before_files:
            copy = backup / path.relative_to(folder)
            copy.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(path, copy)
        try:
            yield
        except BaseException as exc:
            try:
                files, links, dirs = matching()
                for path in files | set(links):
                    if path in before_files or (path in before_links and links.get(path) == before_links[path]):
                        continue  # put back below, or the same link as before
                    path.unlink(missing_ok=True)
                for path, target in before_links.items():
                    if not path.is_symlink() or os.readlink(path) != target:
                        path.unlink(missing_ok=True)
                        path.symlink_to(target)
                for path in before_files:
                    path.parent.mkdir(parents=True, exist_ok=True)
                    os.replace(backup / path.relative_to(folder), path)
                for path in sorted(dirs - before_dirs, key=lambda p: len(p.parts), reverse=True):
                    with contextlib.suppress(OSError):
                        path.rmdir()  # only when empty: a folder holding files the patterns do not cover stays
            except BaseException as undo:
                keep_backup = True
                raise HolousdError(
                    f"{folder}: the run failed ({type(exc).__name__}: {exc}) and putting the folder back failed too "
                    f"({type(undo).__name__}: {undo}); the earlier files are kept in {backup}: move them back by hand"
                ) from exc
            raise
    finally:
        if not keep_backup:
            shutil.rmtree(backup, ignore_errors=True)
