"""Results of a run: per-step arrays and run statistics, written as ``.npz``.

A :class:`Trajectory` holds named series. *Point* series have one entry per accepted state
(the initial one included, K + 1 entries: ``s``, ``t``, ``z`` for RIS, ``t``, ``u`` ... for ELD);
*step* series have one entry per accepted step (K entries: ``tau``, ``I1``, ``I2``, ``lam`` ...).
:class:`RunStatistics` counts accepted and rejected steps, inner solves, Newton iterations,
linear-solver work and the wall time. ``save_npz`` writes every series as an array plus the
statistics under ``stats_<name>`` and ``meta`` as a JSON string, atomically (a temporary file in
the same directory, then a rename: a kill leaves the previous file or the new one).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np


@dataclass
class RunStatistics:
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

    def as_dict(self) -> dict:
        return asdict(self)


class Trajectory:
    """Named per-step series plus statistics and metadata."""

    def __init__(self, meta: dict | None = None):
        self._series: dict[str, list] = {}
        self.stats = RunStatistics()
        self.meta: dict = dict(meta or {})

    def append(self, **values) -> None:
        for key, value in values.items():
            self._series.setdefault(key, []).append(np.asarray(value))

    def entries(self, name: str) -> list:
        """The entries of one series as stored (a list; not a copy)."""
        return self._series.get(name, [])

    def extend(self, name: str, values) -> None:
        """Append several entries to one series (e.g. when restoring from a checkpoint)."""
        self._series.setdefault(name, []).extend(values)

    def __getitem__(self, name: str) -> np.ndarray:
        return np.array(self._series[name])

    def __contains__(self, name: str) -> bool:
        return name in self._series

    def keys(self):
        return self._series.keys()

    def __len__(self) -> int:
        return len(self._series.get("tau", []))

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: np.array(v) for k, v in self._series.items()}

    def save_npz(self, path, extra: dict | None = None) -> Path:
        """Write every series, the statistics and ``meta`` to ``path`` (atomically)."""
        from .atomic import atomic_path

        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        data = self.arrays()
        for key, value in self.stats.as_dict().items():
            data[f"stats_{key}"] = np.asarray(value)
        data["meta"] = np.asarray(json.dumps(self.meta, default=str))
        if extra:
            data.update({k: np.asarray(v) for k, v in extra.items()})
        with atomic_path(path) as tmp:
            np.savez_compressed(tmp, **data)
        return path

    @classmethod
    def load_npz(cls, path) -> Trajectory:
        traj = cls()
        with np.load(path, allow_pickle=False) as f:
            for key in f.files:
                if key == "meta":
                    traj.meta = json.loads(str(f[key]))
                elif key.startswith("stats_"):
                    name = key[len("stats_") :]
                    if hasattr(traj.stats, name):
                        value = f[key].item()
                        setattr(traj.stats, name, value)
                else:
                    traj._series[key] = list(f[key])
        return traj
