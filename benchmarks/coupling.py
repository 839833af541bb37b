"""Seconds per coupled step of the examples against a step of the same body with prescribed data
(issue 19, "Speed": a coupled step costs at most 1.3x the step of the same body with
prescribed data).

For each of ``rothe run eld-tip-mass``, ``eld-tmd`` and ``eld-control`` (their example builders
in :mod:`rothe.eld.examples` at the command's defaults -- size ``--n``, tau -- over ``--steps``
steps), measured in one run of this script, one after the other:

- the coupled run: :func:`rothe.eld.coupled_run.run_coupled` (BDF2, regularized form, nodal
  lifting, ``Uniform(tau)``): eld-tip-mass's bar and mass-spring, eld-tmd's system with the
  absorber, eld-control's with its controller;
- the same body with prescribed data: :func:`rothe.eld.run_eld` on the body alone -- the same
  mesh, element degree, material and damping, the same scheme, form, tau and number of steps --
  with the coupled parts held by prescribed data G(t, x) = A (1 - cos 2 pi t) e_y (so every
  step solves for a moving field, as the coupled one does), fields not stored (the coupled run
  stores none either).

Printed per example: unknowns, the components' coordinates r, steps, the CPU seconds of a step
of each -- the median over all steps of the stepper's ``step`` (the solve, the ledger, the
estimate) plus that of its ``record``, timed by the process clock (BLAS on one thread as in the
evolve loop: CPU time is the work done, not the waits of a shared machine, and the median
ignores the steps another process disturbed) -- and their ratio, over ``--repeat`` alternating
rounds. Target: ratio <= 1.3.

Then ``eld-two-bodies`` (``rothe run eld-two-bodies --compare-union`` at its defaults: the
strip 1 x 0.25 cut at 0.5, P2, E = 100/300, nu = 0.3/0.2, rho = 1/2, plane stress, the
right end pulsed, tau = 0.01) for ``--bodies-n`` cells across: the glued step
(:func:`rothe.eld.bodies.run_bodies`, matching meshes, fields not recorded) against the step of
the single body on the union mesh (:func:`rothe.eld.bodies.strip_union`, ``run_eld``), the
same clock, the same alternating rounds.

    python benchmarks/coupling.py [--n N] [--steps 100] [--repeat 10] [--only eld-tmd,...]
                                  [--bodies-n 2,8,16]
"""

from __future__ import annotations

import argparse
import math
import time
import warnings

import numpy as np

from rothe.eld import BDF2, DirichletData, ELDProblem, Material, run_eld
from rothe.eld.bodies import Body, GluedBodies, run_bodies, strip_pair, strip_union
from rothe.eld.coupled_run import CoupledStepper, run_coupled
from rothe.eld.examples import control_problem, tip_mass_problem, tmd_problem
from rothe.eld.form import Regularized
from rothe.eld.stepper import ELDStepper
from rothe.stepping.controllers import Uniform

#: example -> (builder of the coupled system from n and T, the command's tau and n)
EXAMPLES = {
    "eld-tip-mass": (lambda n, T: tip_mass_problem(n, T=T).system, 0.005, 2),
    "eld-tmd": (lambda n, T: tmd_problem(n, T=T).with_tmd, 0.01, 2),
    "eld-control": (lambda n, T: control_problem(n, T=T).controlled, 0.005, 2),
}


def _motion(amplitude: float = 1e-3):
    w = 2 * math.pi

    def field(t, x, f):
        out = np.zeros_like(x)
        out[1] = amplitude * f(t)
        return out

    return DirichletData(
        lambda t, x: field(t, x, lambda s: 1 - math.cos(w * s)),
        lambda t, x: field(t, x, lambda s: w * math.sin(w * s)),
        lambda t, x: field(t, x, lambda s: w * w * math.cos(w * s)),
    )


def prescribed_body(system, T: float) -> ELDProblem:
    """The body of a coupled system alone, every constrained part (prescribed or coupled) held
    by the prescribed motion :func:`_motion`, at rest at t = 0 (consistent), up to T."""
    body = system.body
    definition = dict(body.definition)
    parts = list(body.constraint.parts)
    definition.update(dirichlet={p: _motion() for p in parts}, u0=None, v0=None, T=T)
    return ELDProblem(body.space.mesh, **definition)


class StepClock:
    """CPU seconds of every call of a stepper's ``step`` and ``record`` (the class's methods
    wrapped while the clock is on): a step of the evolve loop is one of each."""

    def __init__(self, cls):
        self.cls = cls
        self.times: dict[str, list[float]] = {"step": [], "record": []}

    def __enter__(self):
        self.saved = {name: getattr(self.cls, name) for name in self.times}
        for name, original in self.saved.items():
            setattr(self.cls, name, self._timed(original, self.times[name]))
        return self

    def __exit__(self, *exc):
        for name, original in self.saved.items():
            setattr(self.cls, name, original)
        return False

    @staticmethod
    def _timed(original, out: list):
        def timed(*args, **kwargs):
            t0 = time.process_time()
            try:
                return original(*args, **kwargs)
            finally:
                out.append(time.process_time() - t0)

        return timed

    def per_step(self) -> float:
        """The median CPU seconds of a step plus those of a record."""
        return float(np.median(self.times["step"]) + np.median(self.times["record"]))


def measure(name: str, n: int, steps: int, repeat: int) -> dict:
    """CPU seconds per step of the coupled run and of the prescribed one (:class:`StepClock`:
    the medians over all steps of ``repeat`` alternating rounds)."""
    build, tau, _ = EXAMPLES[name]
    scheme, form, control = BDF2(), Regularized("nodal"), Uniform(tau)
    T = steps * tau
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        system = build(n, T)
        alone = prescribed_body(system, T)
        c, p = _per_step(
            lambda: run_coupled(system, scheme=scheme, form=form, control=control, T=T),
            lambda: run_eld(alone, scheme=scheme, form=form, control=control, store_fields=False),
            repeat,
        )
    return {
        "example": name,
        "ndofs": system.body.space.ndofs,
        "r": system.size,
        "steps": steps,
        "coupled_s": c,
        "prescribed_s": p,
        "ratio": c / p,
    }


def _per_step(coupled, prescribed, repeat: int) -> tuple[float, float]:
    """CPU seconds per step of ``coupled()`` (a coupled or glued run) and of ``prescribed()``
    (the body with prescribed data, or the union body), alternating ``repeat`` times."""
    clocks = {"c": StepClock(CoupledStepper), "p": StepClock(ELDStepper)}
    for _ in range(repeat):
        with clocks["c"]:
            coupled()
        with clocks["p"]:
            prescribed()
    return clocks["c"].per_step(), clocks["p"].per_step()


def two_bodies(n: int, T: float):
    """The glued bodies of ``rothe run eld-two-bodies --n1 n`` (defaults) and the union body."""
    mat1 = Material.from_young(100.0, 0.3, 1.0, dim=2, plane="stress")
    mat2 = Material.from_young(300.0, 0.2, 2.0, dim=2, plane="stress")

    def traction(t, x, nrm):
        out = np.zeros_like(x)
        if t < 0.5:
            out[1] = 0.1 * np.sin(np.pi * t / 0.5) ** 2
        return out

    mesh1, mesh2 = strip_pair(1.0, 0.25, 0.5, n, n)
    glued = GluedBodies(
        Body(mesh1, mat1, degree=2, clamped=("left",), name="body1"),
        [
            (
                Body(mesh2, mat2, degree=2, traction={"right": traction}, name="body2"),
                "right",
                "left",
            )
        ],
        T=T,
    )
    union = strip_union(1.0, 0.25, 0.5, n, 2, mat1, mat2, traction={"right": traction}, T=T)
    return glued, union


def measure_bodies(n: int, steps: int, repeat: int) -> dict:
    """CPU seconds per step of the glued run and of the union body's (:class:`StepClock`)."""
    tau = 0.01
    scheme, form, control = BDF2(), Regularized("nodal"), Uniform(tau)
    T = steps * tau
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        glued, union = two_bodies(n, T)
        c, p = _per_step(
            lambda: run_bodies(glued, scheme=scheme, form=form, control=control, fields=False),
            lambda: run_eld(union, scheme=scheme, form=form, control=control, store_fields=False),
            repeat,
        )
    return {
        "example": f"two-bodies n={n}",
        "ndofs": glued.base.space.ndofs,
        "r": glued.system.size,
        "union": union.space.ndofs,
        "steps": steps,
        "coupled_s": c,
        "prescribed_s": p,
        "ratio": c / p,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=None, help="cells across the strip (default 2)")
    ap.add_argument("--steps", type=int, default=100, help="steps per run (default 100)")
    ap.add_argument("--repeat", type=int, default=10)
    ap.add_argument("--only", default=",".join(EXAMPLES))
    ap.add_argument(
        "--bodies-n",
        default="2,8,16",
        help="cells across of the eld-two-bodies rows (default 2,8,16; empty: none)",
    )
    args = ap.parse_args(argv)
    rows = []
    header = (
        f"{'example':14s} {'dofs':>6s} {'r':>2s} {'steps':>6s} {'coupled s/step':>15s} "
        f"{'prescribed s/step':>18s} {'ratio':>6s}"
    )
    print(header)
    for name in [x.strip() for x in args.only.split(",") if x.strip()]:
        _, _, n0 = EXAMPLES[name]
        t0 = time.perf_counter()
        row = measure(name, args.n or n0, args.steps, args.repeat)
        rows.append(row)
        print(
            f"{row['example']:14s} {row['ndofs']:6d} {row['r']:2d} {row['steps']:6d} "
            f"{row['coupled_s']:15.3e} {row['prescribed_s']:18.3e} {row['ratio']:6.2f}"
            f"   ({time.perf_counter() - t0:.0f} s)",
            flush=True,
        )
    sizes = [int(x) for x in args.bodies_n.split(",") if x.strip()]
    if sizes:
        print(
            f"\n{'glued bodies':18s} {'dofs 1':>7s} {'dofs 2':>7s} {'union':>6s} {'steps':>6s} "
            f"{'glued s/step':>13s} {'union s/step':>13s} {'ratio':>6s}"
        )
    for n in sizes:
        t0 = time.perf_counter()
        row = measure_bodies(n, args.steps, args.repeat)
        rows.append(row)
        print(
            f"{row['example']:18s} {row['ndofs']:7d} {row['r']:7d} {row['union']:6d} "
            f"{row['steps']:6d} {row['coupled_s']:13.3e} {row['prescribed_s']:13.3e} "
            f"{row['ratio']:6.2f}   ({time.perf_counter() - t0:.0f} s)",
            flush=True,
        )
    worst = max(r["ratio"] for r in rows)
    print(f"largest ratio {worst:.2f} (target <= 1.3)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
