"""XDMF 3 (+ HDF5) time series of nodal fields on a fixed simplex mesh, for ParaView and meshio.

Layout (the one meshio's ``TimeSeriesWriter`` produces, so ``meshio.xdmf.TimeSeriesReader`` and
ParaView's "XDMF Reader" both read it):

    <name>.xdmf
      Domain
        Grid "mesh" (Uniform): Geometry XY|XYZ -> <name>.h5:/mesh/geometry  (n_nodes, d)
                               Topology Triangle|Tetrahedron -> <name>.h5:/mesh/topology
        Grid "TimeSeries" (Collection, Temporal)
          Grid per step k: xi:include of the mesh, Time Value = s_k (the curve parameter),
                           Information "t" = physical time t_k (if given),
                           Attribute per field (Node-centred) -> <name>.h5:/<field>/<k>
    <name>.h5  (same folder; referenced by its bare file name, so the pair can be moved)

Why not meshio's writer: it creates the .h5 file in the *current working directory* (it uses
``Path(filename).stem``), not next to the .xdmf. Here the HDF5 file always sits beside the XML.
Steps are written as they come (:class:`XdmfSeriesWriter`) so a long run never needs all
snapshots in memory at once; the XML is written on ``close`` (or ``flush``), not at every step,
which would cost O(steps^2) for long runs.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

TOPOLOGY = {3: "Triangle", 4: "Tetrahedron"}  # by nodes per cell
XINCLUDE = "http://www.w3.org/2001/XInclude"
# written as xmlns:xi (ElementTree would call it ns0 otherwise)
ET.register_namespace("xi", XINCLUDE)


class XdmfSeriesWriter:
    """Write a time series of nodal fields on one mesh: ``with XdmfSeriesWriter(p, nodes, cells)``.

    ``nodes``: (n_nodes, d) coordinates (d = 2 or 3); ``cells``: (n_cells, 3 | 4) node indices.
    """

    def __init__(self, path, nodes, cells):
        import h5py

        self.path = Path(path).with_suffix(".xdmf")
        self.h5_path = self.path.with_suffix(".h5")
        nodes = np.ascontiguousarray(nodes, dtype=float)
        cells = np.ascontiguousarray(cells, dtype=np.int64)
        if nodes.ndim != 2 or nodes.shape[1] not in (2, 3):
            raise ValueError(f"nodes: got shape {nodes.shape}, must be (n, 2) or (n, 3)")
        if cells.ndim != 2 or cells.shape[1] not in TOPOLOGY:
            raise ValueError(f"cells: got shape {cells.shape}, must be (m, 3) or (m, 4)")
        self.n_nodes = nodes.shape[0]
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._h5 = h5py.File(self.h5_path, "w")
        self._h5.create_dataset("mesh/geometry", data=nodes)
        self._h5.create_dataset("mesh/topology", data=cells)
        self.steps = 0

        self._root = ET.Element("Xdmf", Version="3.0")
        domain = ET.SubElement(self._root, "Domain")
        grid = ET.SubElement(domain, "Grid", Name="mesh", GridType="Uniform")
        geo = ET.SubElement(grid, "Geometry", GeometryType="XY" if nodes.shape[1] == 2 else "XYZ")
        self._item(geo, "mesh/geometry", nodes)
        topo = ET.SubElement(grid, "Topology", TopologyType=TOPOLOGY[cells.shape[1]],
                             NumberOfElements=str(cells.shape[0]),
                             NodesPerElement=str(cells.shape[1]))
        self._item(topo, "mesh/topology", cells)
        self._series = ET.SubElement(domain, "Grid", Name="TimeSeries", GridType="Collection",
                                     CollectionType="Temporal")

    def _item(self, parent, dataset: str, data: np.ndarray):
        kind = "Float" if data.dtype.kind == "f" else "Int"
        item = ET.SubElement(parent, "DataItem", DataType=kind,
                             Dimensions=" ".join(map(str, data.shape)), Format="HDF",
                             Precision=str(data.dtype.itemsize))
        item.text = f"{self.h5_path.name}:/{dataset}"
        return item

    def write_step(self, time: float, fields: dict[str, np.ndarray], info: dict | None = None):
        """Append one step: ``fields`` maps names to nodal arrays (n_nodes,)."""
        k = self.steps
        arrays = {}
        for name, values in fields.items():  # validate everything before writing anything
            values = np.ascontiguousarray(values, dtype=float)
            if values.shape != (self.n_nodes,):
                raise ValueError(f"{name}: got shape {values.shape}, must be ({self.n_nodes},)")
            arrays[name] = values
        grid = ET.SubElement(self._series, "Grid", Name=f"step_{k}", GridType="Uniform")
        ET.SubElement(grid, f"{{{XINCLUDE}}}include",
                      xpointer='xpointer(//Grid[@Name="mesh"]/*[self::Topology or '
                               'self::Geometry])')
        ET.SubElement(grid, "Time", Value=repr(float(time)))
        for key, value in (info or {}).items():
            ET.SubElement(grid, "Information", Name=str(key), Value=repr(float(value)))
        for name, values in arrays.items():
            ds = f"{name}/{k}"
            self._h5.create_dataset(ds, data=values)
            att = ET.SubElement(grid, "Attribute", Name=name, AttributeType="Scalar",
                                Center="Node")
            self._item(att, ds, values)
        self.steps += 1

    def flush(self):
        """Make the files on disk readable as they are now (HDF5 flushed, XML written)."""
        self._h5.flush()
        self._write_xml()

    def _write_xml(self):
        ET.indent(self._root)
        text = ET.tostring(self._root, encoding="unicode")
        self.path.write_text('<?xml version="1.0"?>\n' + text + "\n")

    def close(self):
        if self._h5 is not None:
            self._write_xml()
            self._h5.close()
            self._h5 = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def write_series(path, nodes, cells, times, fields: dict[str, np.ndarray],
                 info: dict[str, np.ndarray] | None = None) -> Path:
    """Write a whole series at once: ``fields[name]`` has shape (n_steps, n_nodes)."""
    times = np.asarray(times, dtype=float)
    with XdmfSeriesWriter(path, nodes, cells) as w:
        for k, time in enumerate(times):
            w.write_step(time, {name: np.asarray(v)[k] for name, v in fields.items()},
                         {key: np.asarray(v)[k] for key, v in (info or {}).items()})
        return w.path


def read_series(path):
    """(nodes, cells, times, {field: (n_steps, n_nodes)}) via meshio's XDMF reader."""
    import meshio

    with meshio.xdmf.TimeSeriesReader(str(path)) as reader:
        points, cells = reader.read_points_cells()
        times, data = [], {}
        for k in range(reader.num_steps):
            t, point_data, _ = reader.read_data(k)
            times.append(t)
            for name, values in point_data.items():
                data.setdefault(name, []).append(np.asarray(values).ravel())
    return points, cells[0].data, np.array(times), {k: np.array(v) for k, v in data.items()}
