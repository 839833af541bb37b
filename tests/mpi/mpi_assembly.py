"""Run by test_mpi.py under mpiexec: distributed M, K, M_G and lambda's weights against serial."""

import json
import sys
import warnings

import numpy as np
import scipy.sparse as sp
from mpi4py import MPI

from rothe.eld.distributed.problem import DistributedELDProblem
from rothe.eld.examples import beam_problem

warnings.simplefilter("ignore")
comm = MPI.COMM_WORLD
degree = int(sys.argv[1])
p = beam_problem(2, degree=degree)
dp = DistributedELDProblem.from_problem(p)
part = dp.partition
serial_of = np.concatenate(comm.allgather(part.serial_of_own))  # distributed -> serial number
err = {}
for name, A, S in (("M", dp.M, p.M), ("K", dp.K, p.K)):
    ip, jj, vv = A.getValuesCSR()
    mine = sp.csr_matrix((vv, serial_of[jj], ip), shape=(part.n_own, part.n_global))
    ser = sp.csr_matrix(S)[part.serial_of_own]
    diff = abs(mine - ser).max() / abs(ser).max()
    err[name] = comm.allreduce(float(diff), op=MPI.MAX)
    err[name + "_nnz"] = comm.allreduce(int(mine.nnz)) - int(sp.csr_matrix(S).nnz)
c = p.constraint
err["MG"] = float(abs(dp.constraint.boundary_mass - c.boundary_mass).max())
err["dofs"] = int(not np.array_equal(dp.constraint.dofs, c.dofs))
err["owned_sizes"] = comm.allgather(part.n_own)
if comm.rank == 0:
    print(json.dumps(err))
