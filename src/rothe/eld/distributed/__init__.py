"""Elastodynamics on one mesh partitioned over the processes of an MPI job, with PETSc.

``run_eld(..., backend="petsc")`` and ``rothe run eld-beam --backend petsc`` under ``mpiexec``
(docs/scaling.md). Importing this package needs nothing; building a problem or a stepper needs
mpi4py and petsc4py (:func:`rothe.fem.petsc_env.require_petsc` says what to install).

- :mod:`.problem`: :class:`DistributedELDProblem` (partition, distributed M and K, Gamma_D
  replicated), :class:`DistributedDamping`;
- :mod:`.stepper`: :class:`PetscELDStepper`, the serial scheme on the owned dofs;
- :mod:`.run`: :func:`run_eld_petsc` (what ``run_eld(..., backend="petsc")`` calls),
  checkpoints written by rank 0, resume on the same number of processes;
- the command line's ``--backend petsc``: :mod:`rothe.cli.eld_mpi`.
"""
