"""Run by test_mpi.py under mpiexec: SIGTERM on the last rank at step 5, resume, compare; or
SIGUSR1 on the last rank at step 5 (a checkpoint written by all, the run goes on).

argv: checkpoint directory, mode ('interrupt-then-resume' | 'resume' | 'checkpoint-signal')."""

import json
import os
import signal
import sys
import warnings

import numpy as np
from mpi4py import MPI

from rothe.eld import BDF2, run_eld
from rothe.eld.examples import beam_problem
from rothe.errors import RotheInputError, RunInterrupted
from rothe.stepping.controllers import Uniform

warnings.simplefilter("ignore")
comm = MPI.COMM_WORLD
ckpt, mode = sys.argv[1], sys.argv[2]
p = beam_problem(3, degree=1, T=0.12)
kw = dict(scheme=BDF2(), control=Uniform(0.01), solver="amg", linear_rtol=1e-10, backend="petsc")
out = {}


def killer(state, result):
    if state.j == 5 and comm.rank == comm.size - 1:
        os.kill(os.getpid(), signal.SIGTERM)  # one process only: all must stop after step 5


if mode == "interrupt-then-resume":
    full = run_eld(p, **kw).trajectory
    try:
        run_eld(p, observer=killer, checkpoint=ckpt, **kw)
        out["interrupted"] = False
    except RunInterrupted as exc:
        out["interrupted"] = True
        out["steps_at_stop"] = len(exc.trajectory["tau"])
    resumed = run_eld(p, resume=ckpt, **kw).trajectory
    if comm.rank == 0:
        out["equal"] = {
            k: bool(np.array_equal(np.asarray(full[k]), np.asarray(resumed[k])))
            for k in ("t", "u", "v", "lam", "reaction_left", "energy", "balance_residual")
        }
elif mode == "checkpoint-signal":

    def asker(state, result):
        if state.j == 5 and comm.rank == comm.size - 1:
            os.kill(os.getpid(), signal.SIGUSR1)  # one process only: all write the checkpoint

    full = run_eld(p, **kw).trajectory
    asked = run_eld(p, observer=asker, checkpoint=ckpt, progress=True, **kw).trajectory
    if comm.rank == 0:
        out["equal"] = bool(np.array_equal(np.asarray(full["u"]), np.asarray(asked["u"])))
else:
    try:
        run_eld(p, resume=ckpt, **kw)
        out["refused"] = None
    except RotheInputError as exc:
        out["refused"] = str(exc)
if comm.rank == 0:
    print(json.dumps(out))
