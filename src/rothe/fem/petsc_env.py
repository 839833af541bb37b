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
from contextlib import contextmanager

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


#: PETSc's log event around GAMG's Galerkin product P^T A P on its finest level (gamg.c registers
#: "PCGAMG Gal lNN" per level; l00 is the step matrix's)
FINEST_GALERKIN_EVENT = b"PCGAMG Gal l00"


@contextmanager
def finest_level_product(comm, algorithm: str):
    """During the block, PETSc's ``-matptap_via ALGORITHM`` for the Galerkin product of GAMG's
    finest level only; yields False (and sets nothing) where that product cannot be told apart.

    PETSc reads ``-matptap_via`` from the global options when GAMG creates each level's product
    (the products carry no prefix), so an option set around the whole set-up applies to every
    level. The finest product is the one whose A P is large (about 1.3 KB per owned dof on the
    1.07 M-dof beam at N = 2); the coarser products are small but, all-at-once, as slow as the
    finest (docs/scaling.md, eighth session). The option is therefore set and removed by a log
    handler at the begin and end of that product's log event (PETSc's legacy callback handler,
    ``PetscLogHandlerCreateLegacy``, reached through ctypes as :func:`release_product_data`);
    a PETSc built without logging (the event unknown) or without those functions yields False.
    ``comm``: the mpi4py communicator of the set-up.
    """
    from petsc4py import PETSc  # optional, heavy: only where the backend already runs

    try:
        lib = ctypes.CDLL(PETSc.__file__)
        get_id = lib.PetscLogEventGetId
        create, start = lib.PetscLogHandlerCreateLegacy, lib.PetscLogHandlerStart
        stop, destroy = lib.PetscLogHandlerStop, lib.PetscLogHandlerDestroy
    except (OSError, AttributeError):
        yield False
        return
    event = ctypes.c_int(-1)
    get_id.argtypes = [ctypes.c_char_p, ctypes.POINTER(ctypes.c_int)]
    if get_id(FINEST_GALERKIN_EVENT, ctypes.byref(event)) != 0 or event.value < 0:
        yield False
        return
    from mpi4py import MPI  # loaded before petsc4py already (require_petsc)

    options = PETSc.Options()
    eid = event.value

    def begin(e, _i, _o1, _o2, _o3, _o4):
        if e == eid:
            options["matptap_via"] = algorithm
        return 0

    def end(e, _i, _o1, _o2, _o3, _o4):
        if e == eid:
            options.delValue("matptap_via")
        return 0

    callback = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_int, ctypes.c_int, *[ctypes.c_void_p] * 4)
    callbacks = (callback(begin), callback(end))  # referenced until the handler is destroyed
    comm_type = (
        ctypes.c_int if MPI._sizeof(MPI.Comm) == ctypes.sizeof(ctypes.c_int) else ctypes.c_void_p
    )
    create.argtypes = [
        comm_type,
        callback,
        callback,
        ctypes.c_void_p,
        ctypes.c_void_p,
        ctypes.POINTER(ctypes.c_void_p),
    ]
    start.argtypes = stop.argtypes = [ctypes.c_void_p]
    destroy.argtypes = [ctypes.POINTER(ctypes.c_void_p)]
    handler = ctypes.c_void_p()
    if create(MPI._handleof(comm), *callbacks, None, None, ctypes.byref(handler)) != 0:
        yield False
        return
    try:
        if start(handler) != 0:
            yield False
            return
        try:
            yield True
        finally:
            stop(handler)
            options.delValue("matptap_via")  # an error inside the product: not left behind
    finally:
        destroy(ctypes.byref(handler))
        del callbacks
