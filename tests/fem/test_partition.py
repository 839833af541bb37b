"""rothe.fem.distributed.Partition without MPI: the numbering and the owned rows it builds.

(The distributed matrices themselves, on 1 and 2 processes, are tested in tests/mpi.)
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import scipy.sparse as sp

from rothe.fem import mesh as meshes
from rothe.fem.distributed import Partition
from rothe.fem.elasticity import VectorSpace


def _parts(mesh, degree, size):
    return [Partition(mesh, degree, SimpleNamespace(size=size, rank=r), 3) for r in range(size)]


@pytest.mark.parametrize("degree", [1, 2])
def test_one_process_keeps_the_mesh_and_the_serial_numbering(degree):
    mesh = meshes.box(4, 2, 2, 2.0, 1.0, 1.0)
    (part,) = _parts(mesh, degree, 1)
    n = VectorSpace(mesh, degree).ndofs
    assert part.submesh is mesh and part.n_own == part.n_global == n
    for name in ("global_of_local", "own_local", "serial_of_own"):
        np.testing.assert_array_equal(getattr(part, name), np.arange(n), err_msg=name)
    K = VectorSpace(mesh, degree).stiffness(1.0, 1.0)
    R = part.owned_rows(K)
    assert R.has_sorted_indices and abs(R - sp.csr_matrix(K)).max() == 0.0


@pytest.mark.parametrize("degree", [1, 2])
def test_two_parts_own_every_row_once_and_give_the_serial_matrix(degree):
    """The owned rows of both parts' submesh assemblies, stacked, are the serial stiffness
    in the distributed numbering."""
    mesh = meshes.box(4, 2, 2, 2.0, 1.0, 1.0)
    K = sp.csr_matrix(VectorSpace(mesh, degree).stiffness(1.0, 2.0))
    parts = _parts(mesh, degree, 2)
    serial = np.concatenate([p.serial_of_own for p in parts])
    assert np.array_equal(np.sort(serial), np.arange(K.shape[0]))
    stacked = sp.vstack(
        [p.owned_rows(VectorSpace(p.submesh, degree).stiffness(1.0, 2.0)) for p in parts]
    ).tocsr()
    expected = K[serial][:, serial]  # row/column i of the distributed numbering: serial[i]
    assert abs(stacked - expected).max() <= 1e-12 * abs(K).max()
