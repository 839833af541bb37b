"""Runs whose mesh changes from step to step: every distinct mesh once, a mesh id per state.

Time-first discretization lets every Rothe step use its own mesh (issue 8; the ELD paper's
abstract and Sec. 1). A run then produces states on several meshes. :class:`MeshSeries` keeps each
distinct mesh exactly once, keyed by the mesh id that :class:`rothe.fem.adapt.AdaptiveMesh`
assigns (0 = the initial mesh, +1 per change); the trajectory stores, per state, only the id.

In ``trajectory.npz`` the series is the arrays

- ``state_mesh_id`` (n_states,): the mesh of every stored state,
- ``mesh_ids`` (n_meshes,): the ids stored, ascending,
- ``mesh_points_<id>`` (nv, d), ``mesh_cells_<id>`` (nc, d+1): each mesh once.

ParaView output (:func:`write_vtu_series`): one VTU file per stored state, each with its own
grid, and a ``.pvd`` collection that gives every file its time. ParaView opens the ``.pvd`` as
one time-dependent dataset whose grid changes where the mesh changes (the time slider steps
through the files); each VTU also opens on its own, and ``meshio.read`` reads it. Why not one
XDMF temporal collection: meshio's XDMF time-series reader assumes one grid for all steps, so a
file with changing grids would not read back with the library we depend on.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from .atomic import atomic_path, atomic_write_text
from .frozen import frozen

_CELL_TYPES = {2: "line", 3: "triangle", 4: "tetra"}
_KEY = re.compile(r"^mesh_points_(\d+)$")


def _as_mesh(points, cells) -> tuple[np.ndarray, np.ndarray]:
    points = np.ascontiguousarray(points, dtype=float)
    cells = np.ascontiguousarray(cells, dtype=np.int64)
    if points.ndim != 2 or points.shape[1] not in (1, 2, 3):
        raise ValueError(
            f"points must have shape (n_vertices, d) with d in 1..3, got {points.shape}"
        )
    if cells.ndim != 2 or cells.shape[1] not in _CELL_TYPES:
        raise ValueError(f"cells must have shape (n_cells, k) with k in 2..4, got {cells.shape}")
    if cells.size and (cells.min() < 0 or cells.max() >= len(points)):
        raise ValueError(
            f"cells refer to vertices outside 0..{len(points) - 1} "
            f"(range {cells.min()}..{cells.max()})"
        )
    return points, cells


class MeshSeries:
    """Every distinct mesh of a run, stored once under its mesh id.

    ``add`` with an id already present is ignored (the caller registers the mesh of every
    accepted state; only a change brings a new id). Arrays are copied on ``add`` and stored
    read-only (:func:`rothe.io.frozen.frozen`), so later changes of the caller's mesh cannot
    alter what was stored, and a checkpoint writes every mesh once: ``checkpoint_state`` returns
    the same array objects every time and the checkpointer only refers to those it already
    wrote (O(K) in total for K meshes, not O(K^2)).
    """

    def __init__(self) -> None:
        self._meshes: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def add(self, mesh_id: int, points, cells) -> None:
        """Store the mesh (points (n, d), cells (nc, d+1)) under ``mesh_id`` (copied; an id
        already present is ignored).
        """
        mesh_id = int(mesh_id)
        if mesh_id < 0:
            raise ValueError(f"mesh_id must be >= 0, got {mesh_id}")
        if mesh_id in self._meshes:
            return
        points, cells = _as_mesh(points, cells)
        self._meshes[mesh_id] = (frozen(points), frozen(cells))

    def __contains__(self, mesh_id) -> bool:
        return int(mesh_id) in self._meshes

    def __len__(self) -> int:
        return len(self._meshes)

    def mesh(self, mesh_id) -> tuple[np.ndarray, np.ndarray]:
        """(points, cells) of ``mesh_id`` (a KeyError listing the ids if it is not stored)."""
        try:
            return self._meshes[int(mesh_id)]
        except KeyError:
            raise KeyError(f"mesh id {mesh_id} is not in the series (ids: {self.ids})") from None

    @property
    def ids(self) -> list[int]:
        return sorted(self._meshes)

    def n_vertices(self, state_mesh_id) -> np.ndarray:
        """Number of vertices of the mesh of every state (the P1 dofs before constraints)."""
        sizes = {k: len(p) for k, (p, _) in self._meshes.items()}
        return np.array([sizes[int(i)] for i in np.asarray(state_mesh_id).ravel()], dtype=np.int64)

    def _check_states(self, state_mesh_id) -> np.ndarray:
        ids = np.asarray(state_mesh_id, dtype=np.int64).ravel()
        missing = sorted(set(ids.tolist()) - set(self._meshes))
        if missing:
            raise ValueError(f"state_mesh_id refers to meshes not in the series: {missing[:5]}")
        return ids

    def npz_arrays(self, state_mesh_id) -> dict[str, np.ndarray]:
        """The arrays that store the series in an ``.npz`` (module docstring)."""
        out = {
            "state_mesh_id": self._check_states(state_mesh_id),
            "mesh_ids": np.array(self.ids, dtype=np.int64),
        }
        for k in self.ids:
            points, cells = self._meshes[k]
            out[f"mesh_points_{k}"] = points
            out[f"mesh_cells_{k}"] = cells
        return out

    @classmethod
    def from_npz(cls, data) -> tuple[MeshSeries, np.ndarray]:
        """(series, state_mesh_id) from a mapping written by :meth:`npz_arrays` (an ``NpzFile``
        or a dict)."""
        keys = list(data.keys()) if hasattr(data, "keys") else list(data)
        if "mesh_ids" not in keys or "state_mesh_id" not in keys:
            raise ValueError("no mesh series in this file (keys mesh_ids/state_mesh_id missing)")
        series = cls()
        for k in np.asarray(data["mesh_ids"], dtype=np.int64):
            series.add(int(k), data[f"mesh_points_{k}"], data[f"mesh_cells_{k}"])
        extra = [m.group(1) for m in map(_KEY.match, keys) if m and int(m.group(1)) not in series]
        if extra:
            raise ValueError(f"meshes {extra[:5]} are stored but not listed in mesh_ids")
        state_ids = series._check_states(data["state_mesh_id"])
        return series, state_ids

    def checkpoint_state(self) -> dict:
        """Plain dict of arrays (the checkpoint protocol of issue 10: no objects); the meshes
        are the stored (frozen) arrays themselves, written once by the checkpointer."""
        return {
            "ids": np.array(self.ids, dtype=np.int64),
            "points": {str(k): self._meshes[k][0] for k in self.ids},
            "cells": {str(k): self._meshes[k][1] for k in self.ids},
        }

    @classmethod
    def restore_state(cls, data) -> MeshSeries:
        """The series from :meth:`checkpoint_state`'s dict."""
        series = cls()
        for k in np.asarray(data["ids"], dtype=np.int64):
            series.add(int(k), data["points"][str(k)], data["cells"][str(k)])
        return series


def _vtu_field(values, nv: int, name: str) -> np.ndarray:
    values = np.asarray(values, dtype=float)
    if values.shape[0] != nv:
        raise ValueError(
            f"field {name!r} has {values.shape[0]} values, the state's mesh has {nv} vertices"
        )
    if values.ndim == 2 and values.shape[1] == 2:
        # ParaView shows a vector (glyphs, warp) only with three components.
        values = np.column_stack([values, np.zeros(nv)])
    return values


def write_vtu_series(
    directory,
    name: str,
    series: MeshSeries,
    state_mesh_id,
    times,
    point_data,
    *,
    cell_data=None,
    fsync: bool = False,
) -> Path:
    """One VTU per state on its own mesh, and ``<name>.pvd`` indexing them by time.

    ``point_data[i]`` maps field names to vertex values ((nv,) or (nv, d)) on the mesh of state
    ``i``; ``cell_data[i]`` (optional) likewise per cell. Files are ``<name>_000000.vtu``...;
    each is written atomically, the ``.pvd`` last (it is what a reader opens), so an interrupted
    write leaves the previous index valid. Returns the path of the ``.pvd``.
    """
    # heavy: xml.sax.saxutils pulls in urllib.request, http.client, ssl and email (2 MB
    # resident) for every run that imports rothe; only a written series needs it
    from xml.sax.saxutils import quoteattr

    import meshio  # heavy: imported when first needed (start-up time)

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    state_ids = series._check_states(state_mesh_id)
    times = np.asarray(times, dtype=float).ravel()
    n = len(state_ids)
    if len(times) != n or len(point_data) != n or (cell_data is not None and len(cell_data) != n):
        raise ValueError(
            f"state_mesh_id, times, point_data (and cell_data) must have one entry per state: "
            f"got {n}, {len(times)}, {len(point_data)}"
            + ("" if cell_data is None else f", {len(cell_data)}")
        )
    entries = []
    for i in range(n):
        points, cells = series.mesh(state_ids[i])
        nv = len(points)
        pts3 = np.zeros((nv, 3))
        pts3[:, : points.shape[1]] = points
        pdata = {k: _vtu_field(v, nv, k) for k, v in point_data[i].items()}
        cdata = None
        if cell_data is not None and cell_data[i]:
            cdata = {k: [np.asarray(v, dtype=float)] for k, v in cell_data[i].items()}
        mesh = meshio.Mesh(
            pts3, [(_CELL_TYPES[cells.shape[1]], cells)], point_data=pdata, cell_data=cdata
        )
        fname = f"{name}_{i:06d}.vtu"
        with atomic_path(directory / fname, fsync=fsync) as tmp:
            meshio.write(str(tmp), mesh, file_format="vtu")
        entries.append(
            f'    <DataSet timestep="{float(times[i])!r}" group="" part="0" '
            f"file={quoteattr(fname)}/>"
        )
    text = (
        '<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n  <Collection>\n'
        + "\n".join(entries)
        + "\n  </Collection>\n</VTKFile>\n"
    )
    return atomic_write_text(directory / f"{name}.pvd", text)


def read_pvd(path) -> tuple[np.ndarray, list[Path]]:
    """(times, VTU paths) listed in a ``.pvd`` collection written by :func:`write_vtu_series`."""

    path = Path(path)
    root = ET.parse(path).getroot()
    sets = root.findall("./Collection/DataSet")
    times = np.array([float(d.get("timestep")) for d in sets])
    return times, [path.parent / d.get("file") for d in sets]
