"""The mortar projection Pi = D^{-1} M_12 of a non-matching interface: built sparse by blocks
of columns (:func:`rothe.eld.interface.mortar_projection`) against the dense formula it
replaced (``splu(D).solve(M12.toarray())``, the k1 x k2 array, then the small entries dropped).

Interfaces: the strips of ``rothe run eld-two-bodies`` glued by mortar (``--n1 N1 --n2 N2``,
P2: the interface is the strip's height, 2 n + 1 nodes a side) and the faces of two unit cubes
(P1 or P2 tetrahedra, m1 and m2 cells along a face edge: (k m + 1)^2 nodes a side). Printed per
interface: the nodes of the two sides k1, k2, the entries Pi keeps, the seconds and the peak
memory (``tracemalloc``: numpy's allocations) of each way, and the largest difference of the
two results relative to the largest entry.

    python benchmarks/mortar_projection.py [--strips 16:24,24:32] [--cubes 1:12:17,2:16:21]
"""

from __future__ import annotations

import argparse
import time
import tracemalloc

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from skfem import MeshTet

from rothe.eld.bodies import strip_pair
from rothe.eld.interface import PI_DROP, Interface, mortar_projection
from rothe.fem.elasticity import VectorSpace
from rothe.fem.mesh import tag_box_faces


def dense_projection(D, M12) -> sp.csr_matrix:
    """The former construction: the whole k1 x k2 solve, then the drop."""
    Pi = spla.splu(sp.csc_matrix(D)).solve(M12.toarray())
    Pi[np.abs(Pi) < PI_DROP * max(np.abs(Pi).max(), 1e-300)] = 0.0
    return sp.csr_matrix(Pi)


def measured(fn, *args):
    """(result, seconds, peak MB of the allocations during the call)."""
    tracemalloc.start()
    t0 = time.perf_counter()
    out = fn(*args)
    seconds = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    return out, seconds, peak


def cube(x0: float, m: int):
    x = np.linspace(x0, x0 + 1.0, 3)
    y = np.linspace(0.0, 1.0, m + 1)
    return tag_box_faces(MeshTet.init_tensor(x, y, y))


def interfaces(strips, cubes):
    for n1, n2 in strips:
        m1, m2 = strip_pair(1.0, 0.25, 0.5, n1, n2)
        a, b = VectorSpace(m1, 2), VectorSpace(m2, 2)
        yield f"strips n={n1}:{n2} P2", Interface(a, "right", b, "left", method="mortar")
    for degree, m1, m2 in cubes:
        a, b = VectorSpace(cube(0.0, m1), degree), VectorSpace(cube(1.0, m2), degree)
        yield f"cubes m={m1}:{m2} P{degree}", Interface(a, "right", b, "left", method="mortar")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--strips", default="16:24,24:32", help="n1:n2 pairs (default 16:24,24:32)")
    ap.add_argument(
        "--cubes", default="1:12:17,2:16:21", help="degree:m1:m2 triples (default 1:12:17,2:16:21)"
    )
    args = ap.parse_args(argv)
    strips = [tuple(int(v) for v in s.split(":")) for s in args.strips.split(",") if s]
    cubes = [tuple(int(v) for v in s.split(":")) for s in args.cubes.split(",") if s]
    print(
        f"{'interface':22s} {'k1':>6s} {'k2':>6s} {'nnz(Pi)':>9s} {'sparse s':>9s} "
        f"{'sparse MB':>10s} {'dense s':>8s} {'dense MB':>9s} {'difference':>11s}"
    )
    for label, itf in interfaces(strips, cubes):
        D, M12 = itf.D, itf.M12
        new, t_new, mb_new = measured(mortar_projection, D, M12)
        old, t_old, mb_old = measured(dense_projection, D, M12)
        diff = abs(new - old).max() / max(abs(old).max(), 1e-300)
        k1, k2 = M12.shape
        print(
            f"{label:22s} {k1:6d} {k2:6d} {new.nnz:9d} {t_new:9.3f} {mb_new:10.1f} "
            f"{t_old:8.3f} {mb_old:9.1f} {diff:11.1e}",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
