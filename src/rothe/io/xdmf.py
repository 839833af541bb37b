"""XDMF 3 (+ HDF5) time series of nodal fields on a fixed simplex mesh, for ParaView and meshio.

Layout (the one meshio's ``TimeSeriesWriter`` produces, so ``meshio.xdmf.TimeSeriesReader`` and
ParaView's "XDMF Reader" both read it):

    <name>.xdmf
      Domain
        Grid "mesh" (Uniform): Geometry XY|XYZ -> <name>.h5:/mesh/geometry  (n_nodes, d)
                               Topology Triangle|Tetrahedron -> <name>.h5:/mesh/topology
        Grid "TimeSeries" (Collection, Temporal)
          Grid per step k: xi:include of the mesh, Time Value = the step's time,
                           Information per extra value (e.g. "t" = physical time of RIS runs),
                           Attribute per field (Node-centred; Scalar (n,) or Vector (n, 3))
                           -> <name>.h5:/<field>/<k>
    <name>.h5  (same folder; referenced by its bare file name, so the pair can be moved)

Why not meshio's writer: it creates the .h5 file in the *current working directory* (it uses
``Path(filename).stem``), not next to the .xdmf, and it writes in place.

Two writers:

- :class:`XdmfSeriesWriter` (and :func:`write_series`): steps are streamed into a temporary HDF5
  file beside the target, so a long series never needs all snapshots in memory; on ``close`` the
  HDF5 file and then the XML are renamed into place (atomic, :mod:`rothe.io.atomic`). A failure
  (e.g. a full disk: h5py's errors are caught) removes the temporary files and leaves any earlier
  pair untouched.
- :class:`StreamedSeries`: for runs that checkpoint while they stream (eld-beam). Steps go to
  HDF5 *segments* in a work directory; ``checkpoint_state`` closes the open segment (complete on
  disk, an HDF5 file being written when a process is killed can be unreadable) and records the
  steps so far; ``restore_state`` drops what was written after that checkpoint; ``export`` writes
  ``<name>.xdmf`` + ``<name>.h5`` (the segments merged) wherever the results go.
"""

from __future__ import annotations

import contextlib
import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ..errors import OutputWriteError
from .atomic import atomic_path, atomic_write_text, fsync_dir, fsync_file, temporary_name

TOPOLOGY = {3: "Triangle", 4: "Tetrahedron"}  # by nodes per cell
XINCLUDE = "http://www.w3.org/2001/XInclude"
# written as xmlns:xi (ElementTree would call it ns0 otherwise)
ET.register_namespace("xi", XINCLUDE)


def _check_mesh(nodes, cells):
    nodes = np.ascontiguousarray(nodes, dtype=float)
    cells = np.ascontiguousarray(cells, dtype=np.int64)
    if nodes.ndim != 2 or nodes.shape[1] not in (2, 3):
        raise ValueError(f"nodes: got shape {nodes.shape}, must be (n, 2) or (n, 3)")
    if cells.ndim != 2 or cells.shape[1] not in TOPOLOGY:
        raise ValueError(f"cells: got shape {cells.shape}, must be (m, 3) or (m, 4)")
    return nodes, cells


def _check_fields(fields: dict, n_nodes: int) -> dict[str, np.ndarray]:
    """Nodal arrays (n,) or (n, 3); (n, 2) vectors are padded with zeros (ParaView wants 3)."""
    arrays = {}
    for name, values in fields.items():  # validate everything before writing anything
        values = np.ascontiguousarray(values, dtype=float)
        if values.ndim == 2 and values.shape == (n_nodes, 2):
            values = np.column_stack([values, np.zeros(n_nodes)])
        if values.shape not in ((n_nodes,), (n_nodes, 3)):
            raise ValueError(f"{name}: got shape {values.shape}, must be ({n_nodes},) or "
                             f"({n_nodes}, 3)")
        arrays[name] = values
    return arrays


def _h5_error(path, exc: BaseException) -> OutputWriteError:
    return OutputWriteError(path, exc if isinstance(exc, OSError) else OSError(None, str(exc)))


def _item(parent, h5_name: str, dataset: str, shape, dtype):
    kind = "Float" if np.dtype(dtype).kind == "f" else "Int"
    item = ET.SubElement(parent, "DataItem", DataType=kind,
                         Dimensions=" ".join(map(str, shape)), Format="HDF",
                         Precision=str(np.dtype(dtype).itemsize))
    item.text = f"{h5_name}:/{dataset}"
    return item


def xdmf_text(h5_name: str, nodes_shape, cells_shape, steps) -> str:
    """The XML of a series whose heavy data are all in ``h5_name``.

    ``steps``: list of dicts with ``time``, ``info`` (name -> float) and ``fields``
    (name -> shape); field f of step k is the dataset ``f/k``.
    """
    root = ET.Element("Xdmf", Version="3.0")
    domain = ET.SubElement(root, "Domain")
    grid = ET.SubElement(domain, "Grid", Name="mesh", GridType="Uniform")
    geo = ET.SubElement(grid, "Geometry", GeometryType="XY" if nodes_shape[1] == 2 else "XYZ")
    _item(geo, h5_name, "mesh/geometry", nodes_shape, float)
    topo = ET.SubElement(grid, "Topology", TopologyType=TOPOLOGY[cells_shape[1]],
                         NumberOfElements=str(cells_shape[0]),
                         NodesPerElement=str(cells_shape[1]))
    _item(topo, h5_name, "mesh/topology", cells_shape, np.int64)
    series = ET.SubElement(domain, "Grid", Name="TimeSeries", GridType="Collection",
                           CollectionType="Temporal")
    for k, step in enumerate(steps):
        g = ET.SubElement(series, "Grid", Name=f"step_{k}", GridType="Uniform")
        ET.SubElement(g, f"{{{XINCLUDE}}}include",
                      xpointer='xpointer(//Grid[@Name="mesh"]/*[self::Topology or '
                               'self::Geometry])')
        ET.SubElement(g, "Time", Value=repr(float(step["time"])))
        for key, value in (step.get("info") or {}).items():
            ET.SubElement(g, "Information", Name=str(key), Value=repr(float(value)))
        for name, shape in step["fields"].items():
            att = ET.SubElement(g, "Attribute", Name=name,
                                AttributeType="Scalar" if len(shape) == 1 else "Vector",
                                Center="Node")
            _item(att, h5_name, f"{name}/{k}", shape, float)
    ET.indent(root)
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


class XdmfSeriesWriter:
    """Write a time series of nodal fields on one mesh: ``with XdmfSeriesWriter(p, nodes, cells)``.

    ``nodes``: (n_nodes, d) coordinates (d = 2 or 3); ``cells``: (n_cells, 3 | 4) node indices.
    Nothing appears at ``p`` (or its .h5) before ``close``; then both appear, complete.
    """

    def __init__(self, path, nodes, cells):
        import h5py

        self.path = Path(path).with_suffix(".xdmf")
        self.h5_path = self.path.with_suffix(".h5")
        nodes, cells = _check_mesh(nodes, cells)
        self.n_nodes = nodes.shape[0]
        self._shapes = (nodes.shape, cells.shape)
        self.steps: list[dict] = []
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = temporary_name(self.h5_path)
        try:
            self._h5 = h5py.File(self._tmp, "w")
            self._h5.create_dataset("mesh/geometry", data=nodes)
            self._h5.create_dataset("mesh/topology", data=cells)
        except Exception as exc:
            self._discard()
            raise _h5_error(self.h5_path, exc) from exc

    def write_step(self, time: float, fields: dict[str, np.ndarray], info: dict | None = None):
        """Append one step: ``fields`` maps names to nodal arrays (n_nodes,) or (n_nodes, 3)."""
        arrays = _check_fields(fields, self.n_nodes)
        k = len(self.steps)
        try:
            for name, values in arrays.items():
                self._h5.create_dataset(f"{name}/{k}", data=values)
        except Exception as exc:
            self._discard()
            raise _h5_error(self.h5_path, exc) from exc
        self.steps.append({"time": float(time), "info": dict(info or {}),
                           "fields": {n: v.shape for n, v in arrays.items()}})

    def _discard(self) -> None:
        h5, self._h5 = getattr(self, "_h5", None), None
        if h5 is not None:
            with contextlib.suppress(Exception):
                h5.close()
        with contextlib.suppress(OSError):
            os.unlink(self._tmp)

    def close(self):
        """Rename the HDF5 file into place, then write the XML (both atomically)."""
        if self._h5 is None:
            return
        try:
            self._h5.close()
            self._h5 = None
            fsync_file(self._tmp)
        except Exception as exc:
            self._discard()
            raise _h5_error(self.h5_path, exc) from exc
        os.replace(self._tmp, self.h5_path)
        fsync_dir(self.path.parent)
        atomic_write_text(self.path, xdmf_text(self.h5_path.name, *self._shapes, self.steps))

    def abort(self):
        """Forget everything written (the files at the target are left as they were)."""
        self._discard()

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.close()
        else:
            self.abort()
        return False


def write_series(path, nodes, cells, times, fields: dict[str, np.ndarray],
                 info: dict[str, np.ndarray] | None = None) -> Path:
    """Write a whole series at once: ``fields[name]`` has shape (n_steps, n_nodes[, 3])."""
    times = np.asarray(times, dtype=float)
    with XdmfSeriesWriter(path, nodes, cells) as w:
        for k, time in enumerate(times):
            w.write_step(time, {name: np.asarray(v)[k] for name, v in fields.items()},
                         {key: np.asarray(v)[k] for key, v in (info or {}).items()})
    return w.path


class StreamedSeries:
    """An XDMF series streamed into HDF5 segments during a run; checkpointable (module doc).

    ``work_dir``: where the segments ``<name>.seg<k>.h5`` live (e.g. ``OUT/checkpoint/stream``);
    ``export(directory)`` writes ``directory/<name>.xdmf`` and ``<name>.h5``.
    """

    def __init__(self, work_dir, name: str, nodes, cells):
        self.work_dir = Path(work_dir)
        self.name = name
        self.nodes, self.cells = _check_mesh(nodes, cells)
        self.n_nodes = self.nodes.shape[0]
        self.steps: list[dict] = []  # time, info, fields (name -> shape), segment
        self.segments: list[str] = []
        self._h5 = None
        self.work_dir.mkdir(parents=True, exist_ok=True)

    def _segment_path(self, k: int) -> Path:
        return self.work_dir / f"{self.name}.seg{k:05d}.h5"

    def write_step(self, time: float, fields: dict, info: dict | None = None) -> None:
        import h5py

        arrays = _check_fields(fields, self.n_nodes)
        k = len(self.steps)
        path = self._segment_path(len(self.segments))
        try:
            if self._h5 is None:
                self._h5 = h5py.File(path, "w")
                self.segments.append(path.name)
            for name, values in arrays.items():
                self._h5.create_dataset(f"{name}/{k}", data=values)
        except Exception as exc:
            self._close_segment(quiet=True)
            raise _h5_error(path, exc) from exc
        self.steps.append({"time": float(time), "info": dict(info or {}),
                           "fields": {n: list(v.shape) for n, v in arrays.items()},
                           "segment": len(self.segments) - 1})

    def _close_segment(self, quiet: bool = False) -> None:
        h5, self._h5 = self._h5, None
        if h5 is None:
            return
        try:
            path = h5.filename
            h5.close()
            fsync_file(path)
        except Exception as exc:
            if not quiet:
                raise _h5_error(self.work_dir, exc) from exc

    # -- checkpoint protocol ------------------------------------------------------------------
    def checkpoint_state(self) -> dict:
        """Close the open segment (complete on disk) and record the steps written so far."""
        self._close_segment()
        return {"segments": list(self.segments), "steps": [dict(s) for s in self.steps]}

    def restore_state(self, data: dict) -> None:
        self._close_segment(quiet=True)
        self.segments = list(data["segments"])
        self.steps = [dict(s) for s in data["steps"]]
        for s in self.steps:
            s["fields"] = {k: list(v) for k, v in s["fields"].items()}
        keep = set(self.segments)
        for p in self.work_dir.glob(f"{self.name}.seg*.h5"):  # written after that checkpoint
            if p.name not in keep:
                with contextlib.suppress(OSError):
                    p.unlink()
        missing = [s for s in self.segments if not (self.work_dir / s).is_file()]
        if missing:
            from .checkpoint import CheckpointError

            raise CheckpointError(f"{self.work_dir}: the streamed output segment {missing[0]} "
                                  "of the checkpoint is missing")

    # -- export -------------------------------------------------------------------------------
    def export(self, directory) -> Path:
        """``directory/<name>.xdmf`` + ``<name>.h5`` with every step so far (atomically)."""
        import h5py

        self._close_segment()
        directory = Path(directory)
        h5_path = directory / f"{self.name}.h5"
        with atomic_path(h5_path) as tmp:
            try:
                with h5py.File(tmp, "w") as dst:
                    dst.create_dataset("mesh/geometry", data=self.nodes)
                    dst.create_dataset("mesh/topology", data=self.cells)
                    for seg_index, seg in enumerate(self.segments):
                        names = [(k, s) for k, s in enumerate(self.steps)
                                 if s["segment"] == seg_index]
                        if not names:
                            continue
                        with h5py.File(self.work_dir / seg, "r") as src:
                            for k, s in names:
                                for field in s["fields"]:
                                    dst.create_dataset(f"{field}/{k}",
                                                       data=src[f"{field}/{k}"][()])
            except OSError:
                raise
            except Exception as exc:
                raise _h5_error(h5_path, exc) from exc
        steps = [{"time": s["time"], "info": s["info"],
                  "fields": {n: tuple(v) for n, v in s["fields"].items()}} for s in self.steps]
        path = directory / f"{self.name}.xdmf"
        atomic_write_text(path, xdmf_text(h5_path.name, self.nodes.shape, self.cells.shape,
                                          steps))
        return path

    def discard(self) -> None:
        """Remove the segments (after the results were committed)."""
        self._close_segment(quiet=True)
        for seg in self.segments:
            with contextlib.suppress(OSError):
                (self.work_dir / seg).unlink()


def read_series(path):
    """(nodes, cells, times, {field: (n_steps, n_nodes[, 3])}) via meshio's XDMF reader."""
    import meshio

    with meshio.xdmf.TimeSeriesReader(str(path)) as reader:
        points, cells = reader.read_points_cells()
        times, data = [], {}
        for k in range(reader.num_steps):
            t, point_data, _ = reader.read_data(k)
            times.append(t)
            for name, values in point_data.items():
                values = np.asarray(values)
                data.setdefault(name, []).append(values.ravel() if values.ndim == 2
                                                 and values.shape[1] == 1 else values)
    return points, cells[0].data, np.array(times), {k: np.array(v) for k, v in data.items()}
