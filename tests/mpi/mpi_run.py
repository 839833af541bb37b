"""Run by test_mpi.py under mpiexec: short beam runs, distributed against serial."""

import json
import sys
import warnings

import numpy as np
from mpi4py import MPI

from rothe.eld import BDF2, ImplicitEuler, Original, Regularized, run_eld
from rothe.eld.damping import NonlinearDamping
from rothe.eld.distributed import stepper as distributed_stepper
from rothe.eld.examples import beam_problem
from rothe.stepping.controllers import Adaptive, Given, Uniform

warnings.simplefilter("ignore")
released = []  # matrices whose product data each GAMG set-up released
_release = distributed_stepper.release_product_data
distributed_stepper.release_product_data = lambda pc: released.append(_release(pc))
comm = MPI.COMM_WORLD
solver = sys.argv[1]
linear = beam_problem(3, degree=1, T=0.1)
nonlinear = beam_problem(
    3, degree=1, T=0.1, damping=NonlinearDamping(b=0.002, d0=0.5, d_nl=1.0, v_ref=0.05)
)
quadratic = beam_problem(2, degree=2, T=0.05)
FORMS = {"regularized": Regularized(), "original": Original()}
SCHEMES = {"euler": ImplicitEuler(), "bdf2": BDF2()}
out = {}
for p, form, scheme, control in (
    (linear, "regularized", "euler", Uniform(0.01)),
    (linear, "original", "euler", Uniform(0.01)),
    (linear, "regularized", "bdf2", Uniform(0.01)),
    (linear, "regularized", "bdf2", Adaptive(1e-3, tau=0.01)),
    (nonlinear, "regularized", "euler", Uniform(0.01)),
    (nonlinear, "original", "bdf2", Uniform(0.01)),
    (linear, "regularized", "bdf2", Given([0.01] * 4 + [0.02] * 2 + [0.005] * 4)),
    (quadratic, "original", "euler", Uniform(0.01)),
):
    kw = dict(scheme=SCHEMES[scheme], form=FORMS[form], control=control, linear_rtol=1e-12)
    ts = run_eld(p, solver="direct", **kw).trajectory
    tp = run_eld(p, solver=solver, backend="petsc", **kw).trajectory
    if comm.rank == 0:
        R_s, R_p = ts["reaction_left"][-1], tp["reaction_left"][-1]
        us, up = ts["u"][-1], tp["u"][-1]
        name = {id(nonlinear): "nonlinear", id(quadratic): "P2"}.get(id(p), "rayleigh")
        kind = type(control).__name__.lower()
        kind = {"given": "given", "adaptive": "adaptive"}.get(kind, "uniform")
        out[f"{name}-{form}-{scheme}-{kind}"] = {
            "steps": [len(ts["t"]), len(tp["t"])],
            "reaction": float(np.abs(R_s - R_p).max() / np.abs(R_s).max()),
            "u_energy": float(np.sqrt((us - up) @ (p.K @ (us - up)) / (us @ (p.K @ us)))),
            "balance": float(np.max(np.abs(tp["balance_residual"]))),
            "newton": [ts.stats.newton_iterations, tp.stats.newton_iterations],
            "tau": float(np.abs(np.asarray(ts["tau"]) - np.asarray(tp["tau"])).max())
            if len(ts["tau"]) == len(tp["tau"])
            else 1.0,
        }
if comm.rank == 0:
    print(json.dumps({"cases": out, "released": released}))
