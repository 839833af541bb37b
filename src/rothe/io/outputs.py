"""The files of one result, staged and then committed together, ``summary.json`` last.

A command writes every output file of a run (trajectory.npz, figures, XDMF + HDF5, tables) into
a hidden staging directory inside the output directory, ``.rothe-tmp-<pid>-<token>-staging/``,
under their final names (an XDMF file refers to its HDF5 file by name, so names must not change
when the pair is moved). :meth:`OutputSet.commit` then

1. removes the old ``summary.json`` (from now on no summary describes a mix of two runs),
2. renames every staged file into the output directory (each rename is atomic),
3. removes the files the previous summary listed that this run did not write (e.g. figures of
   an earlier run with plots), and
4. renames the new ``summary.json`` into place.

A failure before the commit (a full disk, an error while drawing) removes the staging directory
and leaves the output directory exactly as it was. A SIGKILL during the renames (microseconds)
can leave new files without a summary.json, never a summary beside files of another run;
``summary.json`` and ``trajectory.npz`` carry the run's ``run_id``. A staging directory left by
a killed process is removed by the next run (:func:`~rothe.io.atomic.remove_stale_temporaries`).
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import shutil
from pathlib import Path

from ..errors import OutputWriteError
from .atomic import TMP_PREFIX, fsync_dir, unlink_quietly

SUMMARY = "summary.json"


def read_summary(directory) -> dict | None:
    """The summary.json in ``directory`` as a dict, or None if absent or unreadable."""
    try:
        data = json.loads((Path(directory) / SUMMARY).read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


class OutputSet:
    """``with OutputSet(out) as stage: write files into stage`` -- committed on success."""

    def __init__(self, directory):

        self.directory = Path(directory)
        self.staging = self.directory / f"{TMP_PREFIX}{os.getpid()}-{secrets.token_hex(4)}-staging"
        self.committed: list[str] = []

    def __enter__(self) -> Path:
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            self.staging.mkdir()
        except OSError as exc:
            raise OutputWriteError(self.staging, exc) from exc
        return self.staging

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            try:
                self.commit()
            except BaseException:
                self.abort()
                raise
            return False
        self.abort()
        if isinstance(exc, OutputWriteError) and exc.filename:
            # name the file as the user will look for it, not its staged copy
            staged = Path(exc.filename)
            if self.staging in staged.parents or staged.parent == self.staging:
                final = self.directory / staged.relative_to(self.staging).parts[0]
                raise OutputWriteError(final, OSError(exc.errno, exc.strerror)) from None
        return False

    def abort(self) -> None:
        """Remove the staging directory and what it holds."""
        shutil.rmtree(self.staging, ignore_errors=True)

    def commit(self) -> list[str]:
        """Move the staged files into the directory (``summary.json`` last), remove the files the
        previous summary listed that this result does not have; returns the staged names.
        """
        staged = sorted(p.name for p in self.staging.iterdir() if p.is_file())
        new_summary = self.staging / SUMMARY
        previous = read_summary(self.directory) or {}
        old_files = previous.get("files") if isinstance(previous.get("files"), list) else []
        try:
            if new_summary.exists():
                unlink_quietly(self.directory / SUMMARY)
            for name in staged:
                if name != SUMMARY:
                    os.replace(self.staging / name, self.directory / name)
            for name in set(old_files) - set(staged):
                if isinstance(name, str) and "/" not in name and not name.startswith("."):
                    unlink_quietly(self.directory / name)
            if new_summary.exists():
                os.replace(new_summary, self.directory / SUMMARY)
        except OSError as exc:
            raise OutputWriteError(self.directory, exc) from exc
        fsync_dir(self.directory)
        with contextlib.suppress(OSError):
            self.staging.rmdir()
        self.committed = staged
        return staged
