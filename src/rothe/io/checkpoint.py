"""Checkpoints: everything a run needs to continue bit for bit, in files that need no pickle.

A checkpoint directory (``<out>/checkpoint/`` for the command line) holds

    checkpoint.npz      the current checkpoint: a JSON document (``__checkpoint__``, its UTF-8
                        bytes as a uint8 array) with the nested state, whose numpy arrays are
                        stored beside it as ``a0``, ``a1``, ... and referenced from the JSON as
                        ``{"__array__": "a7"}``
    traj<i>-<seq>.npz   the entries trajectory i gained since the previous checkpoint: append-only
                        segments, written once and referenced by every later checkpoint, so that
                        checkpointing a run of K steps costs O(K) in total, not O(K^2)
    arrays-<seq>.npz    the *frozen* arrays of the state (read-only arrays that own their data,
                        :func:`frozen`: the meshes of a run's mesh series) first seen at
                        checkpoint ``seq``: each written once and referenced by every later
                        checkpoint that still holds it, so a series of K meshes costs O(K) in
                        total too (the checkpoint of an adaptive run used to rewrite every mesh
                        of the series every time: 405 MB per checkpoint at 2 279 meshes)
    stream/             heavy output streamed during the run (eld-beam's XDMF segments)
    .lock               held (flock) by the process that writes the checkpoint

Every file is written atomically (:mod:`rothe.io.atomic`): a kill at any instant leaves the
previous complete ``checkpoint.npz`` (and the segments it references) or the new one. Loading
uses ``np.load(..., allow_pickle=False)``; zip CRCs detect truncated or damaged files, and the
``seal`` (a SHA-256 of the state, the trajectory records and the CRC-32 of every array of the
state, written with them) detects a checkpoint whose state was changed after it was written --
an edited JSON without ``state``, a state vector of another length: such a checkpoint is refused
in one line when it is read, before anything is restored from it.

The JSON document (format ``rothe-checkpoint``, ``format_version`` 2; version 1, without
``external`` and ``seal``, is still read) records

- ``rothe_version``, ``run_id``, ``sequence`` (checkpoints written), ``sessions`` (1 + resumes),
  ``status`` (running | interrupted | failed | completed), ``where`` (step, s, t of the state);
- ``api`` (``run_ris``, ``run_nested``, ``run_eld``) and its ``arguments``, a ``fingerprint`` of
  the problem (:func:`problem_fingerprint`, the problem's own ``fingerprint()``: hashes of the
  assembled matrices, z0 / u0, v0, a few load evaluations), and ``record`` (the caller's, e.g.
  the command line);
- ``state``: ``stepper`` (``stepper.checkpoint_state(state)``), ``controller``
  (``controller.checkpoint_state()``), ``run`` (the driver's context, e.g. which nested run is
  going) and ``attachments`` (objects such as the XDMF stream writer);
- ``trajectories``: per trajectory its ``meta``, ``stats`` and the list of segments;
- ``external``: the arrays of the state stored in ``arrays-<seq>.npz`` files (name -> file,
  key, CRC-32) and ``seal``.

The protocol the state comes from (see docs/robustness.md): a stepper implements
``checkpoint_state(state) -> dict`` and ``restore_state(data) -> state``, a controller
``checkpoint_state() -> dict`` and ``restore_state(data) -> None``; the dicts hold nested
dicts/lists of numpy arrays and Python floats/ints/bools/str/None only (:func:`encode` refuses
anything else, naming where it is).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import re
import time
import uuid
import warnings
import zipfile
import zlib
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from .._version import __version__
from ..errors import OutputWriteError, RotheInputError, check_positive
from .atomic import atomic_path, check_writable, remove_stale_temporaries
from .frozen import frozen, is_frozen
from .trajectory import RAGGED_LENGTHS, RunStatistics, Trajectory

FORMAT = "rothe-checkpoint"
FORMAT_VERSION = 2
#: format versions this rothe reads (1: without frozen arrays and seal)
READABLE_FORMATS = (1, 2)
MAIN = "checkpoint.npz"
CHECKPOINT_SUBDIR = "checkpoint"
STATUSES = ("running", "interrupted", "failed", "completed")
RESUMABLE = ("running", "interrupted", "completed")
_SEGMENT_RE = re.compile(r"^traj(\d+)-(\d+)\.npz$")
_ARRAYS_RE = re.compile(r"^arrays-(\d+)\.npz$")
#: what the JSON document must hold to be a checkpoint at all (besides format and version)
_REQUIRED = {
    "status": str,
    "run_id": str,
    "sequence": int,
    "api": str,
    "state": dict,
    "trajectories": list,
}
_STATE_PARTS = ("stepper", "controller", "run", "attachments")


class CheckpointWarning(UserWarning):
    """A checkpoint could not be written (e.g. a full disk); the run went on."""


class CheckpointError(RotheInputError):
    """A checkpoint cannot be resumed: missing, unreadable, foreign, or for another run.

    The message is one line that says what is wrong (the CLI prints it and exits with 2).
    """


def package_version() -> str:
    """The version of rothe (recorded in, and required of, every checkpoint)."""
    return __version__


def library_versions() -> dict:
    """Versions of the libraries whose rounding a bit-for-bit continuation depends on."""
    import scipy  # heavy: imported when first needed (start-up time)

    out = {"numpy": np.__version__, "scipy": scipy.__version__}
    try:
        import pyamg  # heavy: imported when first needed (start-up time)

        out["pyamg"] = pyamg.__version__
    except ImportError:  # pragma: no cover - a dependency
        pass
    return out


# -- encoding ---------------------------------------------------------------------------------


def encode(obj, arrays: dict, where: str = "state"):
    """The JSON-able image of ``obj``; numpy arrays go to ``arrays`` and are referenced."""
    if isinstance(obj, dict):
        out = {}
        for key, value in obj.items():
            if not isinstance(key, str):
                raise TypeError(f"checkpoint {where}: key {key!r} is not a str")
            out[key] = encode(value, arrays, f"{where}.{key}")
        return out
    if isinstance(obj, (list, tuple)):
        return [encode(v, arrays, f"{where}[{i}]") for i, v in enumerate(obj)]
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind not in "biufcUS":
            raise TypeError(
                f"checkpoint {where}: array of dtype {obj.dtype} (object arrays would need pickle)"
            )
        name = f"a{len(arrays)}"
        arrays[name] = obj
        return {"__array__": name}
    if isinstance(obj, np.generic):
        return obj.item()
    if obj is None or isinstance(obj, (bool, int, float, str)):
        return obj
    raise TypeError(
        f"checkpoint {where}: a {type(obj).__name__} is not allowed (only dicts, "
        "lists, numpy arrays, numbers, str and None)"
    )


def decode(obj, arrays):
    """The inverse of :func:`encode`: ``{'__array__': key}`` replaced by ``arrays[key]``."""
    if isinstance(obj, dict):
        if len(obj) == 1 and "__array__" in obj:
            return arrays[obj["__array__"]]
        return {k: decode(v, arrays) for k, v in obj.items()}
    if isinstance(obj, list):
        return [decode(v, arrays) for v in obj]
    return obj


def normalized(value):
    """A JSON round trip: what a value looks like after it was written and read back."""
    return json.loads(json.dumps(value, default=str))


def _crc(array: np.ndarray) -> int:
    """CRC-32 of an array's dtype, shape and bytes (zlib: about 1 GB/s)."""
    a = np.ascontiguousarray(array)
    crc = zlib.crc32(f"{a.dtype.str}{a.shape}".encode())
    return zlib.crc32(memoryview(a).cast("B") if a.size else b"", crc)


def _seal(header: dict, crcs: dict[str, int]) -> str:
    """SHA-256 of what a resume restores: the state, the trajectory records, the table of
    external arrays, and the CRC-32 of every array (by name)."""
    h = hashlib.sha256()
    part = {k: header.get(k) for k in ("state", "trajectories", "external")}
    h.update(json.dumps(part, sort_keys=True, allow_nan=True).encode())
    for name in sorted(crcs):
        h.update(f"{name}:{crcs[name]:08x};".encode())
    return h.hexdigest()[:32]


def _array_refs(obj, out: list) -> list:
    if isinstance(obj, dict):
        if len(obj) == 1 and "__array__" in obj:
            out.append(obj["__array__"])
        else:
            for v in obj.values():
                _array_refs(v, out)
    elif isinstance(obj, list):
        for v in obj:
            _array_refs(v, out)
    return out


def _check_structure(main: Path, header: dict, arrays: dict | None) -> None:
    """One line if the JSON document is not a checkpoint's (a key missing or of another type,
    or, with ``arrays``, a reference to an array that is not there)."""

    def refuse(what):
        raise CheckpointError(f"{main}: not a readable checkpoint ({what})")

    for key, kind in _REQUIRED.items():
        if key not in header:
            refuse(f"no {key!r} entry")
        if not isinstance(header[key], kind) or (kind is int and isinstance(header[key], bool)):
            refuse(f"{key!r} is a {type(header[key]).__name__}, must be a {kind.__name__}")
    if header["status"] not in STATUSES:
        refuse(f"status {header['status']!r} is not one of {', '.join(STATUSES)}")
    missing = [k for k in _STATE_PARTS if k not in header["state"]]
    if missing:
        refuse(f"its state has no {', '.join(map(repr, missing))}")
    for i, rec in enumerate(header["trajectories"]):
        if not isinstance(rec, dict) or not isinstance(rec.get("segments"), list):
            refuse(f"trajectory {i} has no list of segments")
    if arrays is not None:
        absent = [n for n in _array_refs(header["state"], []) if n not in arrays]
        if absent:
            refuse(f"its state refers to an array {absent[0]!r} that is not stored")


def restored_vector(
    data: dict, key: str, length: int | None = None, *, where: str = "stepper"
) -> np.ndarray:
    """``data[key]`` as a 1-D float array of ``length`` entries, for a stepper's
    ``restore_state``; else :class:`CheckpointError` naming the entry, e.g. ``checkpoint state
    stepper.z: 840 entries, this problem has 841 (the checkpoint is of another problem, or
    damaged)``. A resumed run then never fails later in its first step with a shape error."""
    name = f"checkpoint state {where}.{key}"
    if not isinstance(data, dict) or key not in data:
        raise CheckpointError(f"{name}: missing (the checkpoint is of another stepper, or damaged)")
    value = data[key]
    if not isinstance(value, np.ndarray) or value.ndim != 1 or value.dtype.kind not in "biuf":
        what = (
            f"an array of shape {value.shape} and dtype {value.dtype}"
            if isinstance(value, np.ndarray)
            else f"a {type(value).__name__}"
        )
        raise CheckpointError(f"{name}: {what}, must be a vector of real numbers")
    if length is not None and value.size != int(length):
        raise CheckpointError(
            f"{name}: {value.size} entries, this problem has {int(length)} "
            "(the checkpoint is of another problem, or damaged)"
        )
    return np.array(value, dtype=float)


# -- fingerprints -----------------------------------------------------------------------------


def digest(*items) -> str:
    """A short SHA-256 of arrays / sparse matrices / numbers (dtype, shape and bytes)."""
    import scipy.sparse as sp  # heavy: imported when first needed (start-up time)

    h = hashlib.sha256()
    for item in items:
        if sp.issparse(item):
            item = item.tocsr()
            parts = [item.data, item.indices, item.indptr, np.asarray(item.shape)]
        else:
            parts = [np.asarray(item)]
        for part in parts:
            part = np.ascontiguousarray(part)
            h.update(f"{part.dtype.str}{part.shape}".encode())
            h.update(part.tobytes())
    return h.hexdigest()[:16]


def problem_fingerprint(problem) -> dict:
    """The problem's own ``fingerprint() -> dict`` of cheap hashes, normalized for JSON.

    Every problem supplies it (``RISProblem``, ``FERISProblem``, ``ELDProblem``: assembled
    matrices, initial data, a few loads): this layer knows no family. Each entry is compared
    separately on resume, so the refusal can say what differs.
    """
    custom = getattr(problem, "fingerprint", None)
    if not callable(custom):
        raise TypeError(
            f"cannot fingerprint a {type(problem).__name__}: give it a fingerprint() "
            "method returning a dict of hashes"
        )
    return normalized(dict(custom()))


# -- the checkpoint on disk -------------------------------------------------------------------


def checkpoint_dir(path) -> Path:
    """The checkpoint directory for ``path``: ``path`` itself or ``path/checkpoint``."""
    path = Path(path)
    if (path / MAIN).exists() or not (path / CHECKPOINT_SUBDIR).is_dir():
        return path
    return path / CHECKPOINT_SUBDIR


def changed_keys(old: dict, new: dict) -> list:
    """The keys of either dict whose values differ (a key missing in one counts as None),
    sorted: what a resume reports as changed."""
    return [k for k in sorted(set(old) | set(new)) if old.get(k) != new.get(k)]


def _fmt(value) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, str):
        return repr(value)
    return json.dumps(value, default=str)


class Checkpoint:
    """A checkpoint read from disk (:func:`load_checkpoint`)."""

    def __init__(self, directory: Path, header: dict, arrays: dict):
        self.directory = directory
        self.header = header
        self._arrays = arrays
        self._state = None

    @property
    def external(self) -> dict[str, tuple[str, str, int]]:
        """The frozen arrays of the state stored beside it: name -> (file, key, CRC-32)."""
        return {k: tuple(v) for k, v in (self.header.get("external") or {}).items()}

    def frozen_arrays(self) -> dict[str, np.ndarray]:
        """The loaded frozen arrays by name (what a checkpointer in the same directory adopts
        instead of writing them again)."""
        return {k: self._arrays[k] for k in self.external if k in self._arrays}

    path = property(lambda self: self.directory / MAIN)
    status = property(lambda self: self.header["status"])
    where = property(lambda self: dict(self.header.get("where") or {}))
    record = property(lambda self: dict(self.header.get("record") or {}))
    run_id = property(lambda self: self.header["run_id"])
    sequence = property(lambda self: int(self.header["sequence"]))
    sessions = property(lambda self: int(self.header.get("sessions", 1)))
    api = property(lambda self: self.header["api"])
    every_seconds = property(lambda self: float(self.header.get("every_seconds", 60.0)))

    @property
    def state(self) -> dict:
        """The decoded ``stepper``/``controller``/``run``/``attachments`` state."""
        if self._state is None:
            self._state = decode(self.header["state"], self._arrays)
        return self._state

    def describe_where(self) -> str:
        """Where the run stopped, e.g. ``'accepted_steps = 12, t = 0.3'``."""
        w = self.where
        parts = [
            f"{k} = {w[k]:.6g}" if isinstance(w.get(k), float) else f"{k} = {w[k]}"
            for k in ("accepted_steps", "s", "t")
            if k in w
        ]
        return ", ".join(parts)

    # -- checks -----------------------------------------------------------------------------
    def require_version(self) -> None:
        """Refuse (:class:`CheckpointError`) a checkpoint written by another version of rothe."""
        mine, theirs = package_version(), self.header.get("rothe_version")
        if theirs != mine:
            raise CheckpointError(
                f"{self.directory}: written by rothe {theirs}, this is rothe "
                f"{mine}; resume it with rothe {theirs} or start over"
            )

    def warn_if_libraries_differ(self) -> None:
        """Warn (:class:`CheckpointWarning`) if numpy, scipy, ... differ from those that wrote
        it.
        """
        old, new = self.header.get("libraries") or {}, library_versions()
        diff = [f"{k} {old[k]} -> {new.get(k)}" for k in sorted(old) if old[k] != new.get(k)]
        if diff:
            warnings.warn(
                f"{self.directory}: written with other library versions "
                f"({', '.join(diff)}); the resumed run may differ from an "
                "uninterrupted one in the last bits",
                CheckpointWarning,
                stacklevel=3,
            )

    def require_resumable(self) -> None:
        """Refuse (:class:`CheckpointError`) the checkpoint of a run that failed."""
        if self.status == "failed":
            w = self.where
            raise CheckpointError(
                f"{self.directory}: the run failed ({w.get('failure', 'see summary.json')}); "
                "resuming it would repeat the failure"
            )

    def require_same(self, api: str, arguments: dict, fingerprint: dict | None) -> None:
        """Refuse (one line) if the API, its arguments or the problem differ from the record."""
        if self.api != api:
            raise CheckpointError(f"{self.directory}: the checkpoint is of {self.api}, not {api}")
        old, new = self.header.get("arguments", {}), normalized(arguments)
        diff = [
            f"{k} = {_fmt(new.get(k))} (checkpoint: {_fmt(old.get(k))})"
            for k in changed_keys(old, new)
        ]
        if diff:
            raise CheckpointError(
                f"{self.directory}: the arguments differ from the checkpoint's: {'; '.join(diff)}"
            )
        if fingerprint is not None:
            old = self.header.get("fingerprint", {})
            new = normalized(fingerprint)
            keys = [k for k in sorted(set(old) | set(new)) if old.get(k) != new.get(k)]
            if keys:
                raise CheckpointError(
                    f"{self.directory}: the problem differs from the checkpoint's (in: "
                    f"{', '.join(keys)}); resume with the same problem or start over"
                )

    # -- trajectories -----------------------------------------------------------------------
    @property
    def n_trajectories(self) -> int:
        return len(self.header.get("trajectories", []))

    def trajectory(self, i: int) -> Trajectory:
        """The ``i``-th registered trajectory: its meta data, statistics and series from the
        segment files.
        """
        rec = self.header["trajectories"][i]
        traj = Trajectory(meta=rec.get("meta"))
        for f in fields(RunStatistics):
            if f.name in rec.get("stats", {}):
                setattr(traj.stats, f.name, rec["stats"][f.name])
        for seg in rec["segments"]:
            path = self.directory / seg["file"]
            try:
                with np.load(path, allow_pickle=False) as data:
                    for key, count in seg["counts"].items():
                        if key.endswith(RAGGED_LENGTHS):
                            continue
                        values = traj.unpacked(data, key)
                        if len(values) != count:
                            raise ValueError(f"{key}: {len(values)} entries, expected {count}")
                        traj.extend(key, list(values))
            except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
                raise CheckpointError(
                    f"{path}: a trajectory segment of the checkpoint is missing or damaged ({exc})"
                ) from None
        return traj


def load_checkpoint(path, *, check_version: bool = True, header_only: bool = False) -> Checkpoint:
    """Read a checkpoint (``path`` is the checkpoint directory or a run directory holding one).

    Raises :class:`CheckpointError` with one line for a missing directory, a missing,
    truncated or foreign checkpoint file, or (``check_version``) another rothe version.
    ``header_only``: skip the state's arrays (for status, where, run_id, record).
    """
    path = Path(path)
    if not path.exists():
        raise CheckpointError(f"{path}: no such directory")
    if not path.is_dir():
        raise CheckpointError(f"{path}: not a directory (give the run's output directory)")
    directory = checkpoint_dir(path)
    main = directory / MAIN
    if not main.is_file():
        raise CheckpointError(
            f"{path}: no checkpoint here (no {CHECKPOINT_SUBDIR}/{MAIN}); a run "
            "writes one when it starts"
        )
    try:
        with np.load(main, allow_pickle=False) as data:
            if "__checkpoint__" not in data.files:
                raise CheckpointError(f"{main}: not a rothe checkpoint (no __checkpoint__ entry)")
            raw = data["__checkpoint__"]
            header = json.loads(
                raw.tobytes().decode("utf-8") if raw.dtype == np.uint8 else str(raw)
            )
            arrays = (
                {} if header_only else {k: data[k] for k in data.files if k != "__checkpoint__"}
            )
    except CheckpointError:
        raise
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile) as exc:
        raise CheckpointError(
            f"{main}: not a readable checkpoint (truncated or damaged: {type(exc).__name__}: {exc})"
        ) from None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise CheckpointError(f"{main}: not a rothe checkpoint")
    if header.get("format_version") not in READABLE_FORMATS:
        raise CheckpointError(
            f"{main}: checkpoint format {header.get('format_version')}, this "
            f"rothe reads format {', '.join(map(str, READABLE_FORMATS))}"
        )
    _check_structure(main, header, None)
    if not header_only:
        arrays.update(_load_external(directory, header))
        _check_structure(main, header, arrays)
        if "seal" in header:
            crcs = {name: _crc(a) for name, a in arrays.items()}
            if header["seal"] != _seal(header, crcs):
                raise CheckpointError(
                    f"{main}: not a readable checkpoint (its state differs "
                    "from what rothe wrote: edited or damaged after it was "
                    "written)"
                )
    ckpt = Checkpoint(directory, header, arrays)
    if check_version:
        ckpt.require_version()
    return ckpt


def _load_external(directory: Path, header: dict) -> dict[str, np.ndarray]:
    """The frozen arrays the checkpoint refers to, read from their ``arrays-<seq>.npz`` files
    (each array frozen, so that a checkpointer adopting them does not write them again)."""
    table = header.get("external") or {}
    if not isinstance(table, dict):
        raise CheckpointError(
            f"{directory / MAIN}: not a readable checkpoint ('external' is a "
            f"{type(table).__name__}, must be a dict)"
        )
    by_file: dict[str, list] = {}
    for name, entry in table.items():
        if not (
            isinstance(entry, list)
            and len(entry) == 3
            and isinstance(entry[0], str)
            and _ARRAYS_RE.match(entry[0])
        ):
            raise CheckpointError(
                f"{directory / MAIN}: not a readable checkpoint (external "
                f"array {name!r}: {entry!r})"
            )
        by_file.setdefault(entry[0], []).append((name, entry[1]))
    out = {}
    for file, names in sorted(by_file.items()):
        path = directory / file
        try:
            with np.load(path, allow_pickle=False) as data:
                for name, key in names:
                    out[name] = frozen(data[key])
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
            raise CheckpointError(
                f"{path}: an array file of the checkpoint is missing or "
                f"damaged ({type(exc).__name__}: {exc})"
            ) from None
    return out


# -- writing ----------------------------------------------------------------------------------


@dataclass
class CheckpointOptions:
    """Where and how often a run writes checkpoints.

    ``path``: the checkpoint directory; ``every_seconds``: wall-clock interval between
    checkpoints (one is also written when the run starts, when it stops for any reason, and at
    the end); ``record``: JSON-able data stored with the checkpoint (the command line stores
    its arguments); ``attachments``: name -> object with ``checkpoint_state() -> dict`` and
    ``restore_state(data)`` saved and restored with the run (e.g. a streaming output writer).
    """

    path: str | os.PathLike
    every_seconds: float = 60.0
    record: dict | None = None
    attachments: dict = field(default_factory=dict)

    def __post_init__(self):
        self.path = Path(self.path)
        self.every_seconds = check_positive("checkpoint every_seconds", self.every_seconds)


_HELD: dict[str, list] = {}  # resolved lock path -> [fd, holders] (flock is per open file)


class DirectoryLock:
    """An exclusive ``flock`` on ``<dir>/.lock``: one rothe process per checkpoint directory.

    Re-entrant within a process (the command line holds it for the whole run, the checkpointer
    inside it again); released by the kernel if the process dies, so a killed run never leaves
    a stale lock. Raises :class:`CheckpointError` naming the other process's pid.

    When the last holder releases it and nothing but ``.lock`` is in the directory (no
    checkpoint was written: e.g. a run refused its input after the command line had taken the
    lock), the file and the directory are removed, so a refused run leaves nothing behind. The
    file is unlinked while the lock is still held: a process that opens it at that moment locks
    an unlinked file and proceeds alone, which is harmless because there is nothing to protect.
    """

    def __init__(self, directory):
        self.path = Path(directory) / ".lock"
        self.key = None

    def acquire(self) -> DirectoryLock:
        """Take the lock (re-entrant within the process); :class:`CheckpointError` naming the
        holder's pid if another process holds it. Returns the lock.
        """
        try:
            import fcntl  # POSIX only: elsewhere the lock is a no-op
        except ImportError:  # pragma: no cover - not POSIX
            return self
        self.path.parent.mkdir(parents=True, exist_ok=True)
        key = str(self.path.resolve())
        if key in _HELD:
            _HELD[key][1] += 1
            self.key = key
            return self
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            try:
                other = os.read(fd, 32).decode(errors="replace").strip() or "?"
            finally:
                os.close(fd)
            raise CheckpointError(
                f"{self.path.parent}: in use by another running rothe process (pid {other})"
            ) from None
        os.ftruncate(fd, 0)
        os.write(fd, str(os.getpid()).encode())
        _HELD[key] = [fd, 1]
        self.key = key
        return self

    def release(self) -> None:
        """Release one acquisition; the lock file is unlocked with the last one."""
        if self.key is None:
            return
        key, self.key = self.key, None
        entry = _HELD.get(key)
        if entry is None:
            return
        entry[1] -= 1
        if entry[1] == 0:
            del _HELD[key]
            directory = self.path.parent
            with contextlib.suppress(OSError):
                if [e.name for e in os.scandir(directory)] == [self.path.name]:
                    os.unlink(self.path)
                    with contextlib.suppress(OSError):
                        os.rmdir(directory)
            with contextlib.suppress(OSError):
                os.close(entry[0])

    def __enter__(self):
        return self.acquire()

    def __exit__(self, *exc):
        self.release()
        return False


class Checkpointer:
    """Writes the checkpoints of one run (see the module docstring for the layout).

    The driver (``run_ris``, ``run_nested``, ``run_eld``) registers the run's trajectories,
    keeps ``context`` up to date (e.g. the index of the nested run under way) and calls
    :meth:`save` at the start and at the end; the evolve loop calls :meth:`due` between steps
    and :meth:`save` when it is, and with status ``interrupted`` / ``failed`` when it stops.
    """

    def __init__(
        self,
        options: CheckpointOptions,
        *,
        api: str,
        arguments: dict,
        fingerprint: dict,
        restored: Checkpoint | None = None,
        parameter: str = "checkpoint",
    ):
        self.options = options
        self.directory = Path(options.path)
        self.every = options.every_seconds
        self.api = api
        self.arguments = normalized(arguments)
        self.fingerprint = normalized(fingerprint)
        self.attachments = dict(options.attachments or {})
        self.context: dict = {}
        self.trajectories: list[Trajectory] = []
        self._segments: list[list[dict]] = []
        self._saved: list[dict[str, int]] = []
        self._last = time.monotonic()
        self._warned = False
        # frozen arrays already in a file of this directory: id -> (array, file, key, crc); the
        # array is held so that its id cannot be reused by another object
        self._frozen: dict[int, tuple[np.ndarray, str, str, int]] = {}
        self._external_files: set[str] = set()
        # one line naming the parameter (e.g. checkpoint='/proc/ckpt'), not a FileNotFoundError
        check_writable(self.directory, parameter)
        self._lock = DirectoryLock(self.directory).acquire()
        remove_stale_temporaries(self.directory)
        same_dir = restored is not None and _same_dir(restored.directory, self.directory)
        if restored is not None:
            self.run_id = restored.run_id
            self.sessions = restored.sessions + 1
            self.sequence = restored.sequence
        else:
            self.run_id = uuid.uuid4().hex[:12]
            self.sessions = 1
            self.sequence = 0
        self._adopted = []
        if same_dir:
            for rec in restored.header["trajectories"]:
                self._adopted.append(rec["segments"])
            arrays = restored.frozen_arrays()
            for name, (file, key, crc) in restored.external.items():
                if name in arrays:
                    self._frozen[id(arrays[name])] = (arrays[name], file, key, int(crc))
                    self._external_files.add(file)

    # -- registration ----------------------------------------------------------------------
    def register(self, traj: Trajectory) -> int:
        """Track ``traj``; entries it already holds from a checkpoint in this directory are not
        written again."""
        i = len(self.trajectories)
        self.trajectories.append(traj)
        if i < len(self._adopted):
            segs = [dict(s) for s in self._adopted[i]]
            saved: dict[str, int] = {}
            for s in segs:
                for key, n in s["counts"].items():
                    saved[key] = saved.get(key, 0) + n
            self._segments.append(segs)
            self._saved.append(saved)
        else:
            self._segments.append([])
            self._saved.append({})
        return i

    def due(self) -> bool:
        """True when ``every`` seconds have passed since the last checkpoint."""
        return time.monotonic() - self._last >= self.every

    # -- saving -----------------------------------------------------------------------------
    def save(
        self,
        stepper=None,
        controller=None,
        state=None,
        *,
        status: str = "running",
        where: dict | None = None,
    ) -> Path:
        """Write a checkpoint of the run as it is now; returns the checkpoint directory."""
        if status not in STATUSES:
            raise ValueError(f"status: got {status!r}, must be one of {', '.join(STATUSES)}")
        payload = {
            "stepper": None if stepper is None else stepper.checkpoint_state(state),
            "controller": None if controller is None else controller.checkpoint_state(),
            "run": self.context,
            "attachments": {name: obj.checkpoint_state() for name, obj in self.attachments.items()},
        }
        self.sequence += 1
        seq = self.sequence
        new_segments = []
        traj_records = []
        for i, traj in enumerate(self.trajectories):
            saved = self._saved[i]
            fresh, counts = {}, {}
            for key in traj.keys():
                start = saved.get(key, 0)
                entries = traj.entries(key)
                if len(entries) > start:  # ragged series (varying meshes): flat + lengths
                    packed = traj.packed(key, start)
                    fresh.update(packed)
                    counts.update(dict.fromkeys(packed, len(entries) - start))
            segs = list(self._segments[i])
            if fresh:
                name = f"traj{i}-{seq:06d}.npz"
                with atomic_path(self.directory / name) as tmp:
                    np.savez(tmp, **fresh)
                seg = {"file": name, "counts": counts}
                segs.append(seg)
                new_segments.append((i, seg))
            traj_records.append(
                {"meta": normalized(traj.meta), "stats": traj.stats.as_dict(), "segments": segs}
            )
        arrays: dict = {}
        state = encode(payload, arrays)
        main_arrays, external, fresh_frozen = self._split_frozen(arrays, seq)
        header = {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "rothe_version": package_version(),
            "libraries": library_versions(),
            "run_id": self.run_id,
            "sequence": seq,
            "sessions": self.sessions,
            "written": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "status": status,
            "where": normalized(where or {}),
            "api": self.api,
            "arguments": self.arguments,
            "fingerprint": self.fingerprint,
            "record": normalized(self.options.record or {}),
            "every_seconds": self.every,
            "trajectories": traj_records,
            "state": state,
            "external": {name: [file, key, crc] for name, (file, key, crc) in external.items()},
        }
        header = normalized_header(header)
        crcs = {name: _crc(a) for name, a in main_arrays.items()}
        crcs.update({name: crc for name, (_, _, crc) in external.items()})
        header["seal"] = _seal(header, crcs)
        if fresh_frozen:
            with atomic_path(self.directory / f"arrays-{seq:06d}.npz") as tmp:
                np.savez(tmp, **{key: a for key, a in fresh_frozen.values()})
        text = json.dumps(header, allow_nan=True).encode("utf-8")
        with atomic_path(self.directory / MAIN) as tmp:
            np.savez(tmp, __checkpoint__=np.frombuffer(text, dtype=np.uint8), **main_arrays)
        # only now are the new segments and frozen arrays part of a checkpoint
        for i, seg in new_segments:
            self._segments[i].append(seg)
            for key, n in seg["counts"].items():
                self._saved[i][key] = self._saved[i].get(key, 0) + n
        referenced = {}
        for name, (file, key, crc) in external.items():
            a = arrays[name]
            referenced[id(a)] = (a, file, key, crc)
        self._frozen = referenced  # arrays the state no longer holds are forgotten
        self._external_files = {file for file, _, _ in external.values()}
        self._remove_unreferenced()
        self._last = time.monotonic()
        return self.directory

    def save_or_warn(self, *args, **kwargs) -> Path | None:
        """:meth:`save`, but a write error (a full disk) is a warning, not the end of the run:
        the previous checkpoint stays valid, the run goes on, and the results are still written
        (or fail with their own error). Warns once per run."""

        try:
            return self.save(*args, **kwargs)
        except OutputWriteError as exc:
            self._last = time.monotonic()  # retry at the next interval, not at every step
            if not self._warned:
                self._warned = True
                warnings.warn(
                    f"checkpoint not written ({exc}); the run goes on and the "
                    "previous checkpoint stays",
                    CheckpointWarning,
                    stacklevel=2,
                )
            return None

    def _split_frozen(self, arrays: dict, seq: int):
        """(arrays stored in checkpoint.npz, external name -> (file, key, crc), the frozen
        arrays new in this checkpoint: id -> (key, array)) -- see :func:`frozen`."""
        main, external, fresh = {}, {}, {}
        file = f"arrays-{seq:06d}.npz"
        for name, a in arrays.items():
            if not is_frozen(a):
                main[name] = a
                continue
            known = self._frozen.get(id(a))
            if known is not None and known[0] is a:
                external[name] = known[1:]
                continue
            if id(a) not in fresh:
                fresh[id(a)] = (f"f{len(fresh)}", a)
            key = fresh[id(a)][0]
            external[name] = (file, key, _crc(a))
        return main, external, fresh

    def _remove_unreferenced(self) -> None:
        keep = {s["file"] for segs in self._segments for s in segs} | self._external_files
        with contextlib.suppress(OSError):
            for entry in os.scandir(self.directory):
                if (
                    _SEGMENT_RE.match(entry.name) or _ARRAYS_RE.match(entry.name)
                ) and entry.name not in keep:
                    with contextlib.suppress(OSError):
                        os.unlink(entry.path)

    def close(self) -> None:
        """Release the directory lock."""
        self._lock.release()

    def restore_attachments(self, restored: Checkpoint) -> None:
        """Restore every attachment from its state in the checkpoint ``restored``."""
        saved = restored.state.get("attachments") or {}
        for name, obj in self.attachments.items():
            if name in saved:
                obj.restore_state(saved[name])


def normalized_header(header: dict) -> dict:
    """The header as it reads back from its JSON text (the seal is computed on that)."""
    return json.loads(json.dumps(header, allow_nan=True))


def _same_dir(a: Path, b: Path) -> bool:
    try:
        return Path(a).resolve() == Path(b).resolve()
    except OSError:
        return False


# -- what the drivers call --------------------------------------------------------------------


class RunCheckpointing:
    """Checkpointing and resumption of one driver call (``run_ris``, ``run_nested``, ``run_eld``).

    ``checkpoint``: None, a directory, or :class:`CheckpointOptions`; ``resume``: None, a
    directory or a :class:`Checkpoint`. Resuming checks the version, the status, the API and its
    arguments and the problem's fingerprint (:class:`CheckpointError` with one line otherwise);
    without ``checkpoint`` a resumed run keeps writing checkpoints where it was resumed from,
    at the recorded interval.
    """

    def __init__(self, api: str, problem, arguments: dict, checkpoint=None, resume=None):
        self.restored: Checkpoint | None = None
        self.checkpointer: Checkpointer | None = None
        if checkpoint is None and resume is None:
            return
        fingerprint = problem_fingerprint(problem)
        parameter = "checkpoint"
        if resume is not None:
            ckpt = resume if isinstance(resume, Checkpoint) else load_checkpoint(resume)
            ckpt.require_version()
            ckpt.require_resumable()
            ckpt.require_same(api, arguments, fingerprint)
            ckpt.warn_if_libraries_differ()
            self.restored = ckpt
            if checkpoint is None:
                checkpoint = CheckpointOptions(
                    ckpt.directory, every_seconds=ckpt.every_seconds, record=ckpt.record
                )
                parameter = "resume"  # it keeps writing where it was resumed from
        if not isinstance(checkpoint, CheckpointOptions):
            checkpoint = CheckpointOptions(checkpoint)
        self.checkpointer = Checkpointer(
            checkpoint,
            api=api,
            arguments=arguments,
            fingerprint=fingerprint,
            restored=self.restored,
            parameter=parameter,
        )
        if self.restored is not None:
            try:
                self.checkpointer.restore_attachments(self.restored)
            except BaseException:
                self.close()
                raise

    @property
    def resuming(self) -> bool:
        return self.restored is not None

    def restore(self, stepper, controller=None):
        """``stepper.restore_state`` and ``controller.restore_state`` from the resumed
        checkpoint; returns the state. A state that does not fit the stepper (a key missing, a
        value of another type or shape: a checkpoint of another version of a stepper, or one
        that was changed) is :class:`CheckpointError` with one line, not a traceback. Drivers
        call this instead of the two ``restore_state`` calls."""
        if self.restored is None:
            raise ValueError("restore: this run is not resumed from a checkpoint")
        saved = self.restored.state
        try:
            state = stepper.restore_state(saved["stepper"])
            if controller is not None:
                controller.restore_state(saved["controller"])
        except RotheInputError:
            raise
        except (KeyError, IndexError, TypeError, ValueError, AttributeError) as exc:
            raise CheckpointError(
                f"{self.restored.directory}: the checkpoint's state does not "
                f"fit this run ({type(exc).__name__}: {exc})"
            ) from None
        return state

    def close(self) -> None:
        """Release the checkpoint directory (if the run writes checkpoints)."""
        if self.checkpointer is not None:
            self.checkpointer.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def run_arguments(**kwargs) -> dict:
    """Arguments of a driver call as recorded in a checkpoint (floats kept exactly; inf as str)."""
    out = {}
    for key, value in kwargs.items():
        if isinstance(value, float) and not math.isfinite(value):
            value = repr(value)
        elif isinstance(value, np.ndarray):
            value = {"sha256": digest(value), "shape": list(value.shape)}
        out[key] = value
    return normalized(out)
