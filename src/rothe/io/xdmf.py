"""XDMF 3 (+ HDF5) time series of nodal and cell fields on a fixed simplex mesh, for ParaView and
meshio.

Layout (the one meshio's ``TimeSeriesWriter`` produces, so ``meshio.xdmf.TimeSeriesReader`` and
ParaView's "XDMF Reader" both read it):

    <name>.xdmf
      Domain
        Grid "mesh" (Uniform): Geometry XY|XYZ -> <name>.h5:/mesh/geometry  (n_nodes, d)
                               Topology Triangle|Tetrahedron -> <name>.h5:/mesh/topology
        Grid "TimeSeries" (Collection, Temporal)
          Grid per step k: xi:include of the mesh, Time Value = the step's time,
                           Information per extra value (e.g. "t" = physical time of RIS runs),
                           Attribute per field, Node-centred (n_nodes rows) or Cell-centred
                           (n_cells rows); Scalar (n,), Vector (n, 3) or Tensor (n, 9)
                           -> <name>.h5:/<field>/<k>
    <name>.h5  (same folder; referenced by its bare file name, so the pair can be moved)

Why not meshio's writer: it creates the .h5 file in the *current working directory* (it uses
``Path(filename).stem``), not next to the .xdmf, and it writes in place.

HDF5 never writes to disk here. h5py builds every HDF5 file in memory (a ``BytesIO``), and the
bytes are written with ordinary atomic file I/O (:mod:`rothe.io.atomic`). Writing HDF5 directly
to a full disk made the HDF5 library fail inside its cache flushes: thousands of "Exception
ignored" tracebacks, then a segmentation fault, and a destroyed earlier result. Now a full disk
is an ``OSError`` from ``write`` like any other: one line naming the file, nothing half-written.

Steps are collected in *segments* (one in memory at a time, at most ``MAX_SEGMENT_BYTES``), so
a long series never holds all snapshots in memory:

- :class:`StreamedSeries`: for runs that checkpoint while they stream (eld-beam). Segments are
  written to a work directory when they fill up and at every checkpoint (``checkpoint_state``),
  so a checkpoint never refers to data that exists only in memory; ``restore_state`` drops what
  was written after that checkpoint; ``export(directory)`` writes ``<name>.xdmf`` +
  ``<name>.h5`` (the segments merged, or linked when there is one; a series larger than
  ``MAX_MERGED_BYTES`` stays split into ``<name>.h5``, ``<name>.1.h5``, ... which the XML
  references).
- :class:`XdmfSeriesWriter` (and :func:`write_series`): the same in a temporary work directory;
  on ``close`` the HDF5 file(s) and then the XML appear under their final names, complete.
"""

from __future__ import annotations

import contextlib
import io
import os
import secrets
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ..errors import OutputWriteError
from .atomic import TMP_PREFIX, atomic_path, atomic_write_bytes, atomic_write_text
from .checkpoint import CheckpointError

#: by nodes per cell (lines: the Dirichlet boundary of a 2D body, rothe.eld.output)
TOPOLOGY = {2: "Polyline", 3: "Triangle", 4: "Tetrahedron"}
XINCLUDE = "http://www.w3.org/2001/XInclude"
# written as xmlns:xi (ElementTree would call it ns0 otherwise)
ET.register_namespace("xi", XINCLUDE)


def _check_mesh(nodes, cells):
    nodes = np.ascontiguousarray(nodes, dtype=float)
    cells = np.ascontiguousarray(cells, dtype=np.int64)
    if nodes.ndim != 2 or nodes.shape[1] not in (2, 3):
        raise ValueError(f"nodes: got shape {nodes.shape}, must be (n, 2) or (n, 3)")
    if cells.ndim != 2 or cells.shape[1] not in TOPOLOGY:
        raise ValueError(f"cells: got shape {cells.shape}, must be (m, 2), (m, 3) or (m, 4)")
    return nodes, cells


def _check_fields(fields: dict, n: int, what: str = "nodes") -> dict[str, np.ndarray]:
    """Arrays (n,), (n, 3) or (n, 9) (scalars, vectors, tensors) with one row per node (or per
    cell); (n, 2) vectors are padded with zeros (ParaView wants 3)."""
    arrays = {}
    for name, values in fields.items():  # validate everything before writing anything
        values = np.ascontiguousarray(values, dtype=float)
        if values.ndim == 2 and values.shape == (n, 2):
            values = np.column_stack([values, np.zeros(n)])
        if values.shape not in ((n,), (n, 3), (n, 9)):
            raise ValueError(
                f"{name}: got shape {values.shape}, must be ({n},), ({n}, 3) or "
                f"({n}, 9) (one row per {what[:-1]})"
            )
        arrays[name] = values
    return arrays


_ATTRIBUTE_TYPE = {1: "Scalar", 3: "Vector", 9: "Tensor"}


def _attribute_type(shape) -> str:
    return _ATTRIBUTE_TYPE[1 if len(shape) == 1 else int(shape[1])]


MAX_SEGMENT_BYTES = 256 * 2**20
MAX_MERGED_BYTES = 1024 * 2**20


def _item(parent, h5_name: str, dataset: str, shape, dtype):
    kind = "Float" if np.dtype(dtype).kind == "f" else "Int"
    item = ET.SubElement(
        parent,
        "DataItem",
        DataType=kind,
        Dimensions=" ".join(map(str, shape)),
        Format="HDF",
        Precision=str(np.dtype(dtype).itemsize),
    )
    item.text = f"{h5_name}:/{dataset}"
    return item


def xdmf_text(h5_name: str, nodes_shape, cells_shape, steps) -> str:
    """The XML of a series whose mesh is in ``h5_name``.

    ``steps``: list of dicts with ``time``, ``info`` (name -> float), ``fields``
    (name -> shape, nodal), optionally ``cell_fields`` (name -> shape, one row per cell) and
    ``h5`` (the file of the step's data, default ``h5_name``); field f of step k is the dataset
    ``f/k``.
    """
    root = ET.Element("Xdmf", Version="3.0")
    domain = ET.SubElement(root, "Domain")
    grid = ET.SubElement(domain, "Grid", Name="mesh", GridType="Uniform")
    geo = ET.SubElement(grid, "Geometry", GeometryType="XY" if nodes_shape[1] == 2 else "XYZ")
    _item(geo, h5_name, "mesh/geometry", nodes_shape, float)
    topo = ET.SubElement(
        grid,
        "Topology",
        TopologyType=TOPOLOGY[cells_shape[1]],
        NumberOfElements=str(cells_shape[0]),
        NodesPerElement=str(cells_shape[1]),
    )
    _item(topo, h5_name, "mesh/topology", cells_shape, np.int64)
    series = ET.SubElement(
        domain, "Grid", Name="TimeSeries", GridType="Collection", CollectionType="Temporal"
    )
    for k, step in enumerate(steps):
        g = ET.SubElement(series, "Grid", Name=f"step_{k}", GridType="Uniform")
        ET.SubElement(
            g,
            f"{{{XINCLUDE}}}include",
            xpointer='xpointer(//Grid[@Name="mesh"]/*[self::Topology or self::Geometry])',
        )
        ET.SubElement(g, "Time", Value=repr(float(step["time"])))
        for key, value in (step.get("info") or {}).items():
            ET.SubElement(g, "Information", Name=str(key), Value=repr(float(value)))
        for center, key in (("Node", "fields"), ("Cell", "cell_fields")):
            for name, shape in (step.get(key) or {}).items():
                att = ET.SubElement(
                    g, "Attribute", Name=name, AttributeType=_attribute_type(shape), Center=center
                )
                _item(att, step.get("h5", h5_name), f"{name}/{k}", shape, float)
    ET.indent(root)
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


class _MemoryH5:
    """An HDF5 file built in memory; ``bytes()`` closes it and returns its content."""

    def __init__(self):
        import h5py  # heavy: imported when first needed (start-up time)

        self._bio = io.BytesIO()
        self.file = h5py.File(self._bio, "w")
        self.nbytes = 0

    def put(self, name: str, data: np.ndarray) -> None:
        self.file.create_dataset(name, data=data)
        self.nbytes += data.nbytes

    def bytes(self) -> bytes:
        self.file.close()
        return self._bio.getvalue()

    def discard(self) -> None:
        with contextlib.suppress(Exception):
            self.file.close()


def _link_or_copy(src: Path, dst: Path) -> None:
    """``dst`` becomes a complete copy of the (never modified) file ``src``, atomically: a hard
    link when the file system allows one (no data copied), else a copy."""
    with atomic_path(dst) as tmp:
        try:
            os.link(src, tmp)
        except OSError:
            shutil.copyfile(src, tmp)


class StreamedSeries:
    """An XDMF series collected in HDF5 segments; checkpointable (see the module docstring).

    ``work_dir``: where the segments ``<name>.seg<k>.h5`` are written (e.g.
    ``OUT/checkpoint/stream``); ``export(directory)`` writes ``directory/<name>.xdmf`` and its
    HDF5 file(s).
    """

    def __init__(
        self, work_dir, name: str, nodes, cells, max_segment_bytes: int = MAX_SEGMENT_BYTES
    ):
        self.work_dir = Path(work_dir)
        self.name = name
        self.nodes, self.cells = _check_mesh(nodes, cells)
        self.n_nodes = self.nodes.shape[0]
        self.n_cells = self.cells.shape[0]
        self.max_segment_bytes = int(max_segment_bytes)
        self.steps: list[dict] = []  # time, info, fields (name -> shape), segment index
        self.segments: list[str] = []  # segment files written (complete) in work_dir
        self._open: _MemoryH5 | None = None
        self._pending: bytes | None = None  # a closed segment whose write failed

    def _segment_path(self, k: int) -> Path:
        return self.work_dir / f"{self.name}.seg{k:05d}.h5"

    def write_step(
        self, time: float, fields: dict, info: dict | None = None, cell_fields: dict | None = None
    ) -> None:
        """Append one step: ``fields`` nodal arrays, ``cell_fields`` arrays with one row per
        cell (names distinct from the nodal ones)."""
        arrays = _check_fields(fields, self.n_nodes)
        cell_arrays = _check_fields(cell_fields or {}, self.n_cells, "cells")
        clash = sorted(set(arrays) & set(cell_arrays))
        if clash:
            raise ValueError(f"{clash[0]}: given as a nodal and as a cell field")
        k = len(self.steps)
        if self._open is None:
            self._flush_pending()
            self._open = _MemoryH5()
            if not self.segments:  # the first segment carries the mesh
                self._open.put("mesh/geometry", self.nodes)
                self._open.put("mesh/topology", self.cells)
        for name, values in {**arrays, **cell_arrays}.items():
            self._open.put(f"{name}/{k}", values)
        step = {
            "time": float(time),
            "info": dict(info or {}),
            "fields": {n: list(v.shape) for n, v in arrays.items()},
            "segment": len(self.segments),
        }
        if cell_arrays:
            step["cell_fields"] = {n: list(v.shape) for n, v in cell_arrays.items()}
        self.steps.append(step)
        if self._open.nbytes >= self.max_segment_bytes:
            self._close_segment()

    def _close_segment(self) -> None:
        """Write the segment in memory to its file (atomically)."""
        seg, self._open = self._open, None
        if seg is not None:
            self._pending = seg.bytes()
        self._flush_pending()

    def _flush_pending(self) -> None:
        if self._pending is None:
            return
        self.work_dir.mkdir(parents=True, exist_ok=True)
        path = self._segment_path(len(self.segments))
        atomic_write_bytes(path, self._pending)  # OutputWriteError: kept, retried next time
        self._pending = None
        self.segments.append(path.name)

    # -- checkpoint protocol ------------------------------------------------------------------
    def checkpoint_state(self) -> dict:
        """Write the open segment (the checkpoint must not refer to memory) and record the
        steps so far."""
        self._close_segment()
        return {"segments": list(self.segments), "steps": [dict(s) for s in self.steps]}

    def restore_state(self, data: dict) -> None:
        """Continue from :meth:`checkpoint_state`: the open segment discarded, the segments and
        steps recorded then restored.
        """
        if self._open is not None:
            self._open.discard()
            self._open = None
        self._pending = None
        self.segments = list(data["segments"])
        self.steps = [dict(s) for s in data["steps"]]
        for s in self.steps:
            s["fields"] = {k: list(v) for k, v in s["fields"].items()}
            if "cell_fields" in s:
                s["cell_fields"] = {k: list(v) for k, v in s["cell_fields"].items()}
        keep = set(self.segments)
        for p in self.work_dir.glob(f"{self.name}.seg*.h5"):  # written after that checkpoint
            if p.name not in keep:
                with contextlib.suppress(OSError):
                    p.unlink()
        missing = [s for s in self.segments if not (self.work_dir / s).is_file()]
        if missing:
            raise CheckpointError(
                f"{self.work_dir}: the streamed output segment {missing[0]} "
                "of the checkpoint is missing"
            )

    # -- export -------------------------------------------------------------------------------
    @staticmethod
    def _all_fields(step: dict) -> dict:
        return {**step["fields"], **(step.get("cell_fields") or {})}

    def _data_bytes(self) -> int:
        return sum(
            int(np.prod(shape)) * 8 for s in self.steps for shape in self._all_fields(s).values()
        )

    def export(self, directory) -> Path:
        """``directory/<name>.xdmf`` + its HDF5 file(s) with every step so far (atomically:
        the HDF5 files first, the XML last)."""
        import h5py  # heavy: imported when first needed (start-up time)

        self._close_segment()
        directory = Path(directory)
        main = f"{self.name}.h5"
        steps = [
            {
                "time": s["time"],
                "info": s["info"],
                "fields": {n: tuple(v) for n, v in s["fields"].items()},
                "cell_fields": {n: tuple(v) for n, v in (s.get("cell_fields") or {}).items()},
            }
            for s in self.steps
        ]
        if len(self.segments) == 1:
            _link_or_copy(self.work_dir / self.segments[0], directory / main)
        elif len(self.segments) > 1 and self._data_bytes() <= MAX_MERGED_BYTES:
            merged = _MemoryH5()
            try:
                merged.put("mesh/geometry", self.nodes)
                merged.put("mesh/topology", self.cells)
                for index, seg in enumerate(self.segments):
                    with h5py.File(self.work_dir / seg, "r") as src:
                        for k, s in enumerate(self.steps):
                            if s["segment"] == index:
                                for field in self._all_fields(s):
                                    merged.put(f"{field}/{k}", src[f"{field}/{k}"][()])
                data = merged.bytes()
            except BaseException:
                merged.discard()
                raise
            atomic_write_bytes(directory / main, data)
        elif self.segments:  # too large to merge in memory: one file per segment
            for index, seg in enumerate(self.segments):
                name = main if index == 0 else f"{self.name}.{index}.h5"
                _link_or_copy(self.work_dir / seg, directory / name)
            for s, out in zip(self.steps, steps, strict=True):
                out["h5"] = main if s["segment"] == 0 else f"{self.name}.{s['segment']}.h5"
        else:  # no steps: the mesh alone
            mesh = _MemoryH5()
            mesh.put("mesh/geometry", self.nodes)
            mesh.put("mesh/topology", self.cells)
            atomic_write_bytes(directory / main, mesh.bytes())
        path = directory / f"{self.name}.xdmf"
        atomic_write_text(path, xdmf_text(main, self.nodes.shape, self.cells.shape, steps))
        return path

    def discard(self) -> None:
        """Remove the segments (after the results were committed)."""
        if self._open is not None:
            self._open.discard()
            self._open = None
        for seg in self.segments:
            with contextlib.suppress(OSError):
                (self.work_dir / seg).unlink()


class XdmfSeriesWriter:
    """Write a time series of nodal fields on one mesh: ``with XdmfSeriesWriter(p, nodes, cells)``.

    ``nodes``: (n_nodes, d) coordinates (d = 2 or 3); ``cells``: (n_cells, 2 | 3 | 4) node
    indices (lines, triangles, tetrahedra).
    Nothing appears at ``p`` (or its .h5) before ``close``; then both appear, complete.
    """

    def __init__(self, path, nodes, cells):

        self.path = Path(path).with_suffix(".xdmf")
        self.h5_path = self.path.with_suffix(".h5")
        nodes, cells = _check_mesh(nodes, cells)
        self.n_nodes = nodes.shape[0]
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._work = self.path.parent / (
            f"{TMP_PREFIX}{os.getpid()}-{secrets.token_hex(4)}-{self.path.stem}.parts"
        )
        self._series = StreamedSeries(self._work, self.path.stem, nodes, cells)

    @property
    def steps(self) -> list[dict]:
        return self._series.steps

    def write_step(self, time: float, fields: dict[str, np.ndarray], info: dict | None = None):
        """Append one step: ``fields`` maps names to nodal arrays (n_nodes,) or (n_nodes, 3)."""
        try:
            self._series.write_step(time, fields, info)
        except OutputWriteError as exc:
            raise OutputWriteError(self.h5_path, OSError(exc.errno, exc.strerror)) from None

    def close(self):
        """Write the HDF5 file(s), then the XML, under their final names."""
        if self._series is None:
            return
        try:
            self._series.export(self.path.parent)
        except OutputWriteError as exc:  # name the file the user asked for, not a segment
            target = self.path if str(exc.filename).endswith(".xdmf") else self.h5_path
            raise OutputWriteError(target, OSError(exc.errno, exc.strerror)) from None
        finally:
            self.abort()

    def abort(self):
        """Forget everything written (files at the target are left as they were)."""
        if self._series is not None:
            self._series.discard()
            self._series = None
        shutil.rmtree(self._work, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.close()
        else:
            self.abort()
        return False


def write_series(
    path,
    nodes,
    cells,
    times,
    fields: dict[str, np.ndarray],
    info: dict[str, np.ndarray] | None = None,
) -> Path:
    """Write a whole series at once: ``fields[name]`` has shape (n_steps, n_nodes[, 3])."""
    times = np.asarray(times, dtype=float)
    with XdmfSeriesWriter(path, nodes, cells) as w:
        for k, time in enumerate(times):
            w.write_step(
                time,
                {name: np.asarray(v)[k] for name, v in fields.items()},
                {key: np.asarray(v)[k] for key, v in (info or {}).items()},
            )
    return w.path


def read_series(path):
    """(nodes, cells, times, {field: (n_steps, n_nodes[, 3])}) via meshio's XDMF reader."""
    import meshio  # heavy: imported when first needed (start-up time)

    with meshio.xdmf.TimeSeriesReader(str(path)) as reader:
        points, cells = reader.read_points_cells()
        times, data = [], {}
        for k in range(reader.num_steps):
            t, point_data, _ = reader.read_data(k)
            times.append(t)
            for name, values in point_data.items():
                values = np.asarray(values)
                data.setdefault(name, []).append(
                    values.ravel() if values.ndim == 2 and values.shape[1] == 1 else values
                )
    return points, cells[0].data, np.array(times), {k: np.array(v) for k, v in data.items()}
