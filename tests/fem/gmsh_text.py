"""Write small gmsh 4.1 / 2.2 ASCII files from a scikit-fem mesh, as gmsh itself would.

Every boundary facet goes to one physical group chosen by ``classify(midpoints) -> names``;
the volume cells form the physical group ``domain``. Used only by the tests: no binary mesh files
are committed.
"""

from __future__ import annotations

import numpy as np


def _groups(mesh, classify):
    bf = mesh.boundary_facets()
    facets = mesh.facets[:, bf].T  # (nb, d)
    mid = mesh.p[:, facets].mean(axis=2)  # (dim, nb)
    labels = np.asarray(classify(mid))
    names = sorted(set(labels.tolist()))
    return facets, labels, names


def write_msh41(path, mesh, classify):
    """gmsh 4.1 ASCII: one geometric entity per physical group, all nodes on the volume entity."""
    d = mesh.p.shape[0]
    facets, labels, names = _groups(mesh, classify)
    n = mesh.p.shape[1]
    ftype, ctype = (1, 2) if d == 2 else (2, 4)  # line / triangle, triangle / tetra
    lines = ["$MeshFormat", "4.1 0 8", "$EndMeshFormat", "$PhysicalNames", str(len(names) + 1)]
    for k, name in enumerate(names, start=1):
        lines.append(f'{d - 1} {k} "{name}"')
    lines.append(f'{d} {len(names) + 1} "domain"')
    lines.append("$EndPhysicalNames")
    lo, hi = mesh.p.min(axis=1), mesh.p.max(axis=1)
    box = " ".join(f"{v:g}" for v in (*lo, *([0] * (3 - d)), *hi, *([0] * (3 - d))))
    counts = [0, 0, 0, 0]
    counts[d - 1] = len(names)
    counts[d] = 1
    lines += ["$Entities", " ".join(map(str, counts))]
    for k in range(1, len(names) + 1):
        lines.append(f"{k} {box} 1 {k} 0")
    lines.append(f"1 {box} 1 {len(names) + 1} 0")
    lines.append("$EndEntities")
    lines += ["$Nodes", f"1 {n} 1 {n}", f"{d} 1 0 {n}"]
    lines += [str(i + 1) for i in range(n)]
    pts = np.vstack([mesh.p, np.zeros((3 - d, n))]).T
    lines += [" ".join(f"{v:.17g}" for v in row) for row in pts]
    lines.append("$EndNodes")
    nel = len(facets) + mesh.t.shape[1]
    lines += ["$Elements", f"{len(names) + 1} {nel} 1 {nel}"]
    tag = 1
    for k, name in enumerate(names, start=1):
        rows = facets[labels == name]
        lines.append(f"{d - 1} {k} {ftype} {len(rows)}")
        for r in rows:
            lines.append(f"{tag} " + " ".join(str(i + 1) for i in r))
            tag += 1
    lines.append(f"{d} 1 {ctype} {mesh.t.shape[1]}")
    for r in mesh.t.T:
        lines.append(f"{tag} " + " ".join(str(i + 1) for i in r))
        tag += 1
    lines.append("$EndElements")
    with open(path, "w") as fh:
        fh.write("\n".join(lines) + "\n")
    return path


def write_msh22(path, mesh, classify):
    """gmsh 2.2 ASCII with $PhysicalNames."""
    d = mesh.p.shape[0]
    facets, labels, names = _groups(mesh, classify)
    n = mesh.p.shape[1]
    ftype, ctype = (1, 2) if d == 2 else (2, 4)
    lines = ["$MeshFormat", "2.2 0 8", "$EndMeshFormat", "$PhysicalNames", str(len(names) + 1)]
    for k, name in enumerate(names, start=1):
        lines.append(f'{d - 1} {k} "{name}"')
    lines.append(f'{d} {len(names) + 1} "domain"')
    lines += ["$EndPhysicalNames", "$Nodes", str(n)]
    pts = np.vstack([mesh.p, np.zeros((3 - d, n))]).T
    lines += [f"{i + 1} " + " ".join(f"{v:.17g}" for v in row) for i, row in enumerate(pts)]
    lines += ["$EndNodes", "$Elements", str(len(facets) + mesh.t.shape[1])]
    tag = 1
    for k, name in enumerate(names, start=1):
        for r in facets[labels == name]:
            lines.append(f"{tag} {ftype} 2 {k} {k} " + " ".join(str(i + 1) for i in r))
            tag += 1
    for r in mesh.t.T:
        lines.append(f"{tag} {ctype} 2 {len(names) + 1} 1 " + " ".join(str(i + 1) for i in r))
        tag += 1
    lines.append("$EndElements")
    with open(path, "w") as fh:
        fh.write("\n".join(lines) + "\n")
    return path
