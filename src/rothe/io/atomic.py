"""Atomic file output: write under a temporary name in the same directory, then rename.

``os.replace`` within one directory is atomic on POSIX file systems, so a reader (or a run killed
at any instant, by SIGKILL included) sees either the previous complete file or the new complete
one, never a truncated one. The new file is fsync'ed before the rename and the directory after
it, so the rename also survives a power cut once it has returned.

Temporary names are ``.rothe-tmp-<pid>-<token>-<final name>``: hidden, tied to the writing
process (so a later run can remove the leftovers of a killed one, :func:`remove_stale_temporaries`)
and ending in the final name, so writers that infer the format from the suffix (matplotlib,
``np.savez``) behave as for the final file.

A failed write (a full disk, a read-only file system, a permission) removes the temporary file,
leaves the previous file untouched and raises :class:`~rothe.errors.OutputWriteError`, an
``OSError`` whose message names the path: ``cannot write run1/trajectory.npz: No space left on
device``.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import shutil
from pathlib import Path

from ..errors import OutputWriteError, fail

TMP_PREFIX = ".rothe-tmp-"
_TMP_RE = re.compile(r"^\.rothe-tmp-(\d+)-[0-9a-f]+-")


def temporary_name(path: Path) -> Path:
    """The temporary name ``.rothe-tmp-<pid>-<token>-<name>`` beside ``path``."""
    return path.with_name(f"{TMP_PREFIX}{os.getpid()}-{secrets.token_hex(4)}-{path.name}")


def fsync_file(path) -> None:
    """Flush ``path``'s data to the disk (``os.fsync``)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def fsync_dir(path) -> None:
    """Make a rename in ``path`` durable (a no-op where directories cannot be opened)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def unlink_quietly(path) -> None:
    """Remove ``path``; no error if it cannot be removed (e.g. it does not exist)."""
    with contextlib.suppress(OSError):
        os.unlink(path)


@contextlib.contextmanager
def atomic_path(path, *, fsync: bool = True):
    """``with atomic_path(p) as tmp: write(tmp)`` -- then ``tmp`` is renamed to ``p``.

    On any exception the temporary file is removed and ``p`` is left as it was; an ``OSError``
    (or an error of a writer that wraps one, e.g. h5py's) becomes :class:`OutputWriteError`
    naming ``p``.
    """
    path = Path(path)
    tmp = temporary_name(path)
    try:
        yield tmp
        if fsync:
            fsync_file(tmp)
        os.replace(tmp, path)
    except BaseException as exc:
        unlink_quietly(tmp)
        if isinstance(exc, OutputWriteError):
            raise
        if isinstance(exc, OSError):
            raise OutputWriteError(path, exc) from exc
        raise
    if fsync:
        fsync_dir(path.parent)


def atomic_write_bytes(path, data: bytes, *, fsync: bool = True) -> Path:
    """Write ``data`` to ``path`` atomically (module docstring); returns ``path``."""
    path = Path(path)
    with atomic_path(path, fsync=fsync) as tmp, open(tmp, "wb") as f:
        f.write(data)
    return path


def atomic_write_text(path, text: str, *, fsync: bool = True) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns ``path``."""
    return atomic_write_bytes(path, text.encode("utf-8"), fsync=fsync)


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_temporaries(directory) -> int:
    """Remove temporary files (and directories) left by killed writers in ``directory``.

    Only names of the form ``.rothe-tmp-<pid>-...`` whose process no longer exists are touched.
    Returns how many were removed.
    """

    directory = Path(directory)
    removed = 0
    try:
        entries = list(directory.iterdir())
    except OSError:
        return 0
    for entry in entries:
        m = _TMP_RE.match(entry.name)
        if m is None or _alive(int(m.group(1))):
            continue
        try:
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()
            removed += 1
        except OSError:
            pass
    return removed


def check_writable(directory, name: str = "directory") -> Path:
    """Create ``directory`` if needed and prove that files can be created and renamed in it.

    Raises :class:`~rothe.errors.RotheInputError` naming ``name`` (the caller's parameter; the
    command line passes its option), e.g. ``--out: got
    '/proc/x', cannot create or write this directory ([Errno 2] No such file or directory)``.
    Meant to run before the first step, so that a read-only or missing location is refused
    at once instead of after the whole run.
    """

    directory = Path(directory)
    if directory.exists() and not directory.is_dir():
        raise fail(name, str(directory), "must be a directory (a file of that name exists)")
    try:
        directory.mkdir(parents=True, exist_ok=True)
        probe = temporary_name(directory / "write-test")
        with open(probe, "wb") as f:
            f.write(b"rothe")
            f.flush()
            os.fsync(f.fileno())
        final = probe.with_name(probe.name + ".renamed")
        os.replace(probe, final)
        os.unlink(final)
    except OSError as exc:
        reason = exc.strerror or str(exc)
        code = f"[Errno {exc.errno}] " if exc.errno is not None else ""
        raise fail(
            name,
            str(directory),
            f"cannot create or write files in this directory ({code}{reason})",
        ) from None
    return directory
