"""Cost of the coupled step's linear algebra against a step with prescribed data (issue 19,
phase 1: the kernel only; ``benchmarks/coupling.py`` with the examples is phase 2's).

A 2D P2 strip clamped on 'left'; the coupled run ties 'right' to a rigid body (r = 3) and adds
a PD controller fed by a tip velocity sensor (s = 1). Per step, the prescribed-data step does:
the residual of the known part r_k = rho M a_k + C v_k + K u_k - F and one back-substitution
with A_II; the coupled step does the same plus the border: Phi^T r_k, Phi c_q, the sensor rows,
the (r + s) Schur solve and x_I = x_0 - X q. Printed: seconds per step of each and the ratio
(target <= 1.3), and the one-off cost per factorization (r back-substitutions for X).

    python benchmarks/coupling_kernel.py [--nx 64] [--steps 50]
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
from skfem import MeshTri

from rothe.eld import ELDProblem, Material, RayleighDamping
from rothe.eld.components import RigidBody
from rothe.eld.control import LinearController, PointSensor
from rothe.eld.coupled_step import CoupledStepSystem
from rothe.eld.coupling import CoupledProblem, RigidMotion
from rothe.fem.mesh import tag_box_faces
from rothe.stepping.evolve import single_threaded_blas


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--nx", type=int, default=64)
    ap.add_argument("--steps", type=int, default=50)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    mesh = tag_box_faces(
        MeshTri.init_tensor(np.linspace(0, 4, 4 * args.nx + 1), np.linspace(0, 1, args.nx + 1))
    )
    mat = Material.from_young(100.0, 0.3, 1.0, dim=2)
    body = RigidBody(1.0, 0.1, [4.1, 0.5], reference=[4.0, 0.5])
    ctrl = LinearController.pd(
        0.5,
        0.1,
        PointSensor([3.9, 0.5], "velocity", axes=[0]),
        body,
        filter_time=0.01,
        directions=[1.0, 0.0, 0.0],
    )
    problem = ELDProblem(
        mesh,
        mat,
        degree=2,
        damping=RayleighDamping(0.0, 0.001),
        dirichlet={"left": lambda t, x: 0 * x},
    )
    system = CoupledProblem(problem, [body], [RigidMotion("right", body)], [ctrl])
    kern = CoupledStepSystem(system)
    n, I = problem.space.ndofs, kern.I
    kap = 1.5 / 0.01
    t0 = time.perf_counter()
    kern.factor(kap * kap, kap, 1.0, 1.0, kap, kap)
    t_factor = time.perf_counter() - t0
    lu = kern._lu
    M, K, C = kern.M, kern.K, kern.D.linear
    rng = np.random.default_rng(0)
    a_k, v_k, u_k, F = (rng.standard_normal(n) for _ in range(4))
    Phi, c_q = kern.Phi, rng.standard_normal(kern.r)
    Jq = kap * kap * kern.Mq

    def prescribed():
        r_k = kern.rho * (M @ a_k) + C @ v_k + K @ u_k - F
        return lu.solve(-r_k[I])

    def coupled():
        r_k = kern.rho * (M @ (a_k + Phi @ c_q)) + C @ v_k + K @ u_k - F
        y_k = kern.Y_u @ u_k + kern.Y_v @ v_k - kern._LZ.T @ r_k
        rhs_q = -(Phi.T @ r_k) + kern.E @ (kern.Dc @ y_k)
        return kern.solve(-r_k[I], rhs_q, kern.Bc @ y_k, Jq)

    for f in (prescribed, coupled):  # warm up
        f()
    times = {}
    for f in (prescribed, coupled, prescribed, coupled):
        t0 = time.perf_counter()
        for _ in range(args.steps):
            f()
        times.setdefault(f.__name__, []).append((time.perf_counter() - t0) / args.steps)
    tp, tc = min(times["prescribed"]), min(times["coupled"])
    t0 = time.perf_counter()
    lu.solve(np.zeros(I.size))
    t_bs = time.perf_counter() - t0
    print(f"2D P2 strip, {n} dofs, rigid body (r = {kern.r}) + PD controller (s = {kern.s})")
    print(f"factorization of A_II: {t_factor:.3f} s (incl. {kern.r} back-substitutions for X)")
    print(
        f"s/step prescribed data: {tp * 1e3:.2f} ms; coupled: {tc * 1e3:.2f} ms; "
        f"ratio {tc / tp:.3f} (target <= 1.3); one back-substitution {t_bs * 1e3:.2f} ms"
    )


if __name__ == "__main__":
    with single_threaded_blas():  # as inside the evolve loop (threaded level-1 BLAS spins)
        main()
