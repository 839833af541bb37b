"""Figures of runs whose mesh changes: degrees of freedom over the run, mesh snapshots."""

from __future__ import annotations

import numpy as np

from .common import draw_edges, plt, save_figure, snapshot_axes, snapshot_grid


def plot_dofs(path, t, dofs, s=None, title=None) -> None:
    """Degrees of freedom of every stored state against t, and against the arc length s in a
    second panel when ``s`` is given (RIS: the jumps happen at fixed t, spread out in s)."""
    t = np.asarray(t, dtype=float)
    dofs = np.asarray(dofs, dtype=float)
    panels = 1 if s is None else 2
    fig, axes = plt.subplots(1, panels, figsize=(5.0 * panels, 3.6), squeeze=False)
    axes = axes[0]
    axes[0].step(t, dofs, where="post", color="C0")
    axes[0].set_xlabel("t")
    axes[0].set_ylabel("degrees of freedom")
    if s is not None:
        axes[1].step(np.asarray(s, dtype=float), dofs, where="post", color="C1")
        axes[1].set_xlabel("s (arc length)")
        axes[1].set_ylabel("degrees of freedom")
    for ax in axes:
        ax.grid(True, alpha=0.3)
    if title:
        fig.suptitle(title)
    save_figure(fig, path)


def _visible_triangles(points: np.ndarray, cells: np.ndarray):
    """2D: the mesh itself. 3D: the boundary faces seen from +z, projected onto the x-y plane
    (faces found by sorting the packed vertex triples: no loop over cells)."""
    if points.shape[1] == 2:
        return points, cells
    faces = np.concatenate(
        [cells[:, [1, 2, 3]], cells[:, [0, 2, 3]], cells[:, [0, 1, 3]], cells[:, [0, 1, 2]]]
    )
    opposite = np.concatenate([cells[:, 0], cells[:, 1], cells[:, 2], cells[:, 3]])
    key = np.sort(faces, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    boundary = counts[inverse.ravel()] == 1
    faces, opposite = faces[boundary], opposite[boundary]
    p = points[faces]
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    # orient outwards: away from the cell's fourth vertex
    outward = np.einsum("ij,ij->i", normal, p[:, 0] - points[opposite]) > 0
    normal[~outward] *= -1
    return points[:, :2], faces[normal[:, 2] > 1e-14 * np.abs(normal).max()]


def plot_mesh_snapshots(
    path,
    series,
    state_mesh_id,
    times,
    values,
    indices,
    title=None,
    label: str = "value at the vertices",
) -> None:
    """Mesh and a vertex field at the states ``indices`` (one panel each): one colour scale
    (its bar labelled ``label``), the cell edges, the vertices of each mesh in its panel's
    title; panels sized by the domain's aspect ratio (no empty margins).

    ``values[i]`` holds the vertex values (nv,) of state ``i`` on its own mesh; only the entries
    at ``indices`` are read. 3D meshes show their boundary as seen from +z. The title says what
    is shown after the caller's ``title`` (the run), with the range of mesh sizes over the
    panels.
    """
    indices = [int(i) for i in indices]
    if not indices:
        raise ValueError("indices must name at least one state")
    state_mesh_id = np.asarray(state_mesh_id).ravel()
    meshes = [series.mesh(state_mesh_id[i]) for i in indices]
    lo_xy = np.min([p[:, :2].min(axis=0) for p, _ in meshes], axis=0)
    hi_xy = np.max([p[:, :2].max(axis=0) for p, _ in meshes], axis=0)
    fig, axes = snapshot_grid(len(indices), hi_xy - lo_xy)
    vals = [np.asarray(values[i], dtype=float) for i in indices]
    vals = [np.linalg.norm(v, axis=1) if v.ndim == 2 else v for v in vals]
    lo = min(float(v.min()) for v in vals)
    hi = max(float(v.max()) for v in vals)
    if hi <= lo:
        hi = lo + 1.0
    pc = None
    for k, (ax, i, v, (points, cells)) in enumerate(zip(axes, indices, vals, meshes, strict=True)):
        xy, tri = _visible_triangles(points, cells)
        pc = ax.tripcolor(
            xy[:, 0], xy[:, 1], tri, v, shading="gouraud", vmin=lo, vmax=hi, cmap="viridis"
        )
        draw_edges(ax, xy[:, 0], xy[:, 1], tri)
        snapshot_axes(ax, first=k == 0)
        ax.set_title(f"t = {times[i]:.4g}, {len(points)} vertices", fontsize=9)
    fig.colorbar(pc, ax=list(axes), shrink=0.9, label=label)
    sizes = [len(p) for p, _ in meshes]
    span = f"{min(sizes)}" if min(sizes) == max(sizes) else f"{min(sizes)}-{max(sizes)}"
    what = f"{label} on the adapted meshes ({span} vertices)"
    fig.suptitle(f"{title}: {what}" if title else what, fontsize=10)
    save_figure(fig, path, tight=False)
