"""Results of a run: per-step arrays and run statistics, written as ``.npz``.

A :class:`Trajectory` holds named series. *Point* series have one entry per accepted state
(the initial one included, K + 1 entries: ``s``, ``t``, ``z`` for RIS, ``t``, ``u`` ... for ELD);
*step* series have one entry per accepted step (K entries: ``tau``, ``I1``, ``I2``, ``lam`` ...).
:class:`RunStatistics` counts accepted and rejected steps, inner solves, Newton iterations,
linear-solver work and the wall time. ``save_npz`` writes every series as an array plus the
statistics under ``stats_<name>`` and ``meta`` as a JSON string, atomically (a temporary file in
the same directory, then a rename: a kill leaves the previous file or the new one).

*Ragged* series (:meth:`Trajectory.set_ragged`) hold 1-D entries of varying length: z of a run
whose mesh changes between steps. ``t["z"]`` is then a list of arrays; the ``.npz`` stores
``z_flat`` (the entries concatenated) and ``z_offsets`` (entry i is
``z_flat[z_offsets[i]:z_offsets[i + 1]]``), and ``load_npz`` rebuilds the list. A trajectory
with ``meshes`` (a :class:`rothe.io.mesh_series.MeshSeries`) also stores every distinct mesh
once and ``state_mesh_id``, the mesh of every stored z (the ``z_mesh_id`` series). Runs on a
fixed mesh keep the plain format (``z`` one (K + 1, n) array).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from .atomic import atomic_path
from .mesh_series import MeshSeries


@dataclass
class RunStatistics:
    """Counters and timings of a run (summed over the sessions of a resumed run).

    Attributes
    ----------
    accepted_steps, rejected_steps : int
    inner_solves : int
        Every attempt of a step (accepted, rejected, shortened to land on T).
    newton_iterations : int
        Iterations of the inner solvers, all attempts.
    fb_steps : int
        Forward-backward fallback steps among them.
    linear_factorizations : int
        LU factorizations or AMG setups.
    linear_solves, krylov_iterations : int
    landing_retries : int
        Steps redone shorter to land on T.
    wall_time_s : float
    seconds : dict
        Wall-clock seconds by phase (step, adapt, estimate, mark, refine, transfer, rebuild,
        factor, solve, record, checkpoint).
    """

    accepted_steps: int = 0
    rejected_steps: int = 0
    inner_solves: int = 0  # every attempt (accepted, rejected, shortened to land on T)
    newton_iterations: int = 0  # iterations of the inner solvers, all attempts
    fb_steps: int = 0  # forward-backward fallback steps among them
    linear_factorizations: int = 0  # LU factorizations or AMG setups
    linear_solves: int = 0
    krylov_iterations: int = 0
    landing_retries: int = 0  # steps redone shorter to land on T
    wall_time_s: float = 0.0  # summed over all sessions of a resumed run
    #: wall-clock seconds by phase (rothe.timing): step, adapt, estimate, mark, refine,
    #: transfer, rebuild, factor, solve, record, checkpoint; summed over sessions
    seconds: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        """The statistics as a dict (``seconds`` a dict by phase)."""
        return asdict(self)

    def untimed(self) -> dict:
        """The counts without the wall-clock times (what a repeated or resumed run reproduces)."""
        out = self.as_dict()
        for key in TIMED_STATISTICS:
            out.pop(key)
        return out


#: the statistics that are wall-clock times (differ between two runs of the same computation)
TIMED_STATISTICS = ("wall_time_s", "seconds")


def is_timing_array(name: str) -> bool:
    """Whether an array of ``trajectory.npz`` is a wall-clock time (``stats_wall_time_s``,
    ``stats_seconds_<phase>``) rather than a result."""
    return name == "stats_wall_time_s" or name.startswith("stats_seconds_")


#: key suffix of the entry lengths of a ragged series in a checkpoint segment
RAGGED_LENGTHS = "__lengths"


class Trajectory:
    """Named per-step series plus statistics and metadata.

    Parameters
    ----------
    meta : dict, optional
        Meta data of the run (saved as JSON with the series).
    """

    def __init__(self, meta: dict | None = None):
        self._series: dict[str, list] = {}
        self._ragged: set[str] = set()
        self.stats = RunStatistics()
        self.meta: dict = dict(meta or {})
        #: every distinct mesh of a run whose mesh changes (MeshSeries), else None
        self.meshes = None

    def set_ragged(self, *names: str) -> None:
        """Let these series hold 1-D entries of varying length (module docstring)."""
        self._ragged.update(names)

    def is_ragged(self, name: str) -> bool:
        """Whether the series ``name`` has entries of different lengths (stored flat with
        offsets).
        """
        return name in self._ragged

    def packed(self, name: str, start: int = 0) -> dict[str, np.ndarray]:
        """Entries ``start:`` of one series as arrays: ``{name: stacked}``, or for a ragged
        series ``{name: concatenated, name + RAGGED_LENGTHS: lengths}`` (checkpoint segments)."""
        entries = [np.asarray(e) for e in self._series.get(name, [])[start:]]
        if name not in self._ragged:
            return {name: np.stack(entries)}
        return {
            name: np.concatenate(entries) if entries else np.zeros(0),
            name + RAGGED_LENGTHS: np.array([e.size for e in entries], dtype=np.int64),
        }

    def unpacked(self, data, name: str) -> list:
        """The entries of ``name`` from arrays written by :meth:`packed` (marks it ragged)."""
        if name + RAGGED_LENGTHS not in data:
            return list(data[name])
        self._ragged.add(name)
        lengths = np.asarray(data[name + RAGGED_LENGTHS], dtype=np.int64)
        return np.split(np.asarray(data[name]), np.cumsum(lengths)[:-1]) if lengths.size else []

    def append(self, **values) -> None:
        """Append one entry to each named series (a new series for a new name)."""
        for key, value in values.items():
            self._series.setdefault(key, []).append(np.asarray(value))

    def entries(self, name: str) -> list:
        """The entries of one series as stored (a list; not a copy)."""
        return self._series.get(name, [])

    def extend(self, name: str, values) -> None:
        """Append several entries to one series (e.g. when restoring from a checkpoint)."""
        self._series.setdefault(name, []).extend(values)

    def __getitem__(self, name: str) -> np.ndarray:
        if name in self._ragged:  # entries of varying length: a list of arrays
            return [np.asarray(e) for e in self._series[name]]
        return np.array(self._series[name])

    def __contains__(self, name: str) -> bool:
        return name in self._series

    def keys(self):
        """The names of the series."""
        return self._series.keys()

    def __len__(self) -> int:
        return len(self._series.get("tau", []))

    def arrays(self) -> dict[str, np.ndarray]:
        """Every series as an array (a ragged one as ``<name>_flat`` and ``<name>_offsets``), and
        the meshes of a space-adaptive run.
        """
        out = {}
        for k, v in self._series.items():
            if k in self._ragged:
                sizes = [np.asarray(e).size for e in v]
                out[f"{k}_flat"] = (
                    np.concatenate([np.asarray(e, dtype=float).ravel() for e in v])
                    if v
                    else np.zeros(0)
                )
                out[f"{k}_offsets"] = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
            else:
                out[k] = np.array(v)
        if self.meshes is not None:
            ids = self._series.get("z_mesh_id", [])
            out.update(self.meshes.npz_arrays(np.array(ids, dtype=np.int64)))
        return out

    def save_npz(self, path, extra: dict | None = None) -> Path:
        """Write every series, the statistics and ``meta`` to ``path`` (atomically)."""

        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        data = self.arrays()
        for key, value in self.stats.as_dict().items():
            if key == "seconds":  # one array per phase
                for phase, seconds in value.items():
                    data[f"stats_seconds_{phase}"] = np.asarray(seconds)
                continue
            data[f"stats_{key}"] = np.asarray(value)
        data["meta"] = np.asarray(json.dumps(self.meta, default=str))
        if extra:
            data.update({k: np.asarray(v) for k, v in extra.items()})
        with atomic_path(path) as tmp:
            np.savez_compressed(tmp, **data)
        return path

    @classmethod
    def load_npz(cls, path) -> Trajectory:
        """The trajectory that :meth:`save_npz` wrote to ``path`` (series, statistics, meta and
        meshes).
        """
        traj = cls()
        with np.load(path, allow_pickle=False) as f:
            files = set(f.files)
            if "mesh_ids" in files:
                traj.meshes, _ = MeshSeries.from_npz(f)
            for key in f.files:
                if key in ("mesh_ids", "state_mesh_id") or key.startswith(
                    ("mesh_points_", "mesh_cells_")
                ):
                    continue
                if key.endswith("_flat") and key[:-5] + "_offsets" in files:
                    name = key[:-5]
                    off = f[name + "_offsets"]
                    flat = f[key]
                    traj._series[name] = [flat[a:b] for a, b in zip(off[:-1], off[1:], strict=True)]
                    traj._ragged.add(name)
                    continue
                if key.endswith("_offsets") and key[:-8] + "_flat" in files:
                    continue
                if key == "meta":
                    traj.meta = json.loads(str(f[key]))
                elif key.startswith("stats_seconds_"):
                    traj.stats.seconds[key[len("stats_seconds_") :]] = float(f[key])
                elif key.startswith("stats_"):
                    name = key[len("stats_") :]
                    if hasattr(traj.stats, name):
                        value = f[key].item()
                        setattr(traj.stats, name, value)
                else:
                    traj._series[key] = list(f[key])
        return traj
