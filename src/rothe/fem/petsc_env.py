"""petsc4py and mpi4py for the distributed backend, imported on demand with a one-line refusal.

Serial ``rothe`` never imports this module's targets: PETSc is an optional extra
(``pip install 'rothe[mpi]'``). The PyPI wheel ``dolfinx-solver-real`` (Python >= 3.12) bundles
petsc4py with PETSc 3.25 (MUMPS, GAMG); its bindings need ``mpi4py.MPI`` loaded first (else
petsc4py fails with ``libmpi.so.12: cannot open shared object file``), which is why ``mpi4py`` is
imported before ``petsc4py`` here. On clusters petsc4py comes from the module system, Spack or
conda-forge and the same order is harmless.
"""

from __future__ import annotations

import ctypes
import os

from ..errors import RotheInputError

#: what to install, said once wherever the backend is refused
INSTALL_HINT = (
    "pip install 'rothe[mpi]' (mpi4py) plus petsc4py: on Python >= 3.12 "
    "'pip install dolfinx-solver-real', on a cluster the petsc4py of its PETSc module"
)


def require_petsc(option: str = "backend 'petsc'"):
    """(MPI, PETSc): the modules, or :class:`RotheInputError` naming what is missing."""
    try:
        import dolfinx_solver  # noqa: F401 - the wheel: orders mpi4py ahead of its bindings
    except ImportError:
        pass
    # mpi4py and petsc4py: optional and heavy, imported only when the backend is asked for
    try:
        from mpi4py import MPI
    except ImportError as exc:
        raise RotheInputError(
            f"{option}: needs mpi4py ({exc}); install it: {INSTALL_HINT}"
        ) from None
    try:
        from petsc4py import PETSc  # optional, heavy: after mpi4py (module docstring)
    except ImportError as exc:
        raise RotheInputError(
            f"{option}: needs petsc4py ({exc}); install it: {INSTALL_HINT}"
        ) from None
    return MPI, PETSc


def petsc_available() -> str | None:
    """None if petsc4py and mpi4py import, else the reason (for tests that skip)."""
    try:
        require_petsc()
    except RotheInputError as exc:
        return str(exc)
    return None


#: the environment variables through which MPI launchers tell a process the job's size: MPICH's
#: Hydra and srun with PMI (PMI_SIZE), Open MPI (OMPI_COMM_WORLD_SIZE)
LAUNCHER_SIZE_VARIABLES = ("PMI_SIZE", "OMPI_COMM_WORLD_SIZE")


def launched_processes() -> int:
    """The number of processes of the MPI job this process was started in (``mpiexec -n N``),
    read from the launcher's environment without starting MPI; 1 outside a launcher."""
    for name in LAUNCHER_SIZE_VARIABLES:
        value = os.environ.get(name, "")
        if value.isdigit() and int(value) > 0:
            return int(value)
    return 1


def release_product_data(pc) -> int:
    """Free what PETSc keeps with the Galerkin products of a set-up multigrid ``pc``; returns
    how many matrices were cleared (0 where the C function cannot be reached).

    GAMG forms each coarse operator as P^T A P (and smooths P by a product A T); PETSc keeps the
    symbolic data of every product (on MPI the off-process rows of P and the A P block) in the
    result, for a numeric re-product with the same pattern, which rothe never asks for: it sets
    up a new hierarchy when the step matrix changes. ``MatProductClear`` drops it (measured on
    the 1.07 M-dof beam, N = 2: 850 MB per process after the steps; docs/scaling.md). petsc4py
    does not wrap that function, so it is called through ctypes from the library petsc4py's
    extension module links (dlsym on that module searches its dependencies).
    """
    from petsc4py import PETSc  # optional, heavy: only where the backend already runs

    try:
        clear = ctypes.CDLL(PETSc.__file__).MatProductClear
    except (OSError, AttributeError):  # a build without the symbol: keep the data
        return 0
    clear.argtypes = [ctypes.c_void_p]
    clear.restype = ctypes.c_int
    levels = pc.getMGLevels()
    operators = [pc.getMGSmoother(level).getOperators()[0] for level in range(levels)]
    interpolations = [pc.getMGInterpolation(level) for level in range(1, levels)]
    for mat in operators + interpolations:
        if clear(mat.handle) != 0:
            raise RuntimeError("MatProductClear failed on a matrix of the multigrid hierarchy")
    return len(operators) + len(interpolations)
