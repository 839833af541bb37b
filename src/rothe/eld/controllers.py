"""Step controllers of the elastodynamics runs (all on the shared evolve loop).

The step-control objects of :mod:`rothe.stepping.controllers` become controllers here
(:func:`rothe.eld.run.prepare_eld_run`):

- ``Uniform(tau)`` (n = T/tau equal steps) and ``Given(steps)`` (a user's sequence tau_1, ...,
  tau_n): :class:`~rothe.stepping.controllers.FixedStepController`. Every step is accepted; a
  step that failed (Newton or a linear solve did not converge, or the state is not finite)
  stops the run with :class:`~rothe.errors.RunFailed` naming the step: a fixed grid has no
  other step to try, and a failed step is never accepted.
- ``Adaptive(tol, ...)``: :class:`rothe.stepping.controllers.ErrorNormController` with the
  stepper's local error estimate (``result.errors['local_error']``, see
  :mod:`rothe.eld.stepper`), order 1 (Euler) or 2 (BDF2), safety 0.9, factors in [0.2, 2],
  no growth right after a rejection, and never above the solvability bound of the next step or
  (BDF2) :data:`~rothe.eld.scheme.BDF2_RATIO_CAP` times the last accepted step
  (:func:`adaptive_controller`).

:func:`step_controller` builds the controller of a step-control object; :func:`describe_run`
adds what a run says about itself (the trajectory's meta data) and what its checkpoint must
match, for both backends of :func:`rothe.eld.run_eld`.
"""

from __future__ import annotations

import math
from dataclasses import asdict

from ..errors import fail
from ..io.checkpoint import run_arguments
from ..stepping.controllers import Adaptive, ErrorNormController, FixedStepController, Given


def adaptive_controller(
    stepper, tol: float, tau0: float, *, tau_min: float, tau_max: float
) -> ErrorNormController:
    """The adaptive controller for an :class:`~rothe.eld.stepper.ELDStepper`.

    Parameters
    ----------
    stepper : ELDStepper
        Its ``order``, ``max_ratio`` and ``max_step`` (the solvability bound) set the limits.
    tol : float
        The tolerance of the local error estimate.
    tau0 : float
        The first step.
    tau_min, tau_max : float
        The range of the steps.

    Returns
    -------
    ErrorNormController
    """
    return ErrorNormController(
        tol,
        tau0,
        stepper.order,
        key="local_error",
        safety=0.9,
        fac_min=0.2,
        fac_max=2.0,
        fac_fail=0.25,
        max_ratio=stepper.max_ratio,
        tau_min=tau_min,
        tau_max=tau_max,
        step_bound=stepper.max_step,
    )


def step_controller(stepper, control, T: float, info: dict):
    """The runtime controller of the step-control object ``control`` for ``stepper`` (a serial
    or distributed ELD stepper with ``tau``, ``steps``, ``n_steps``, ``max_ratio``): adaptive
    steps get :func:`~rothe.eld.controllers.adaptive_controller` with tau_min (default
    1e-10 T) and tau_max (default T) checked against the first step, recorded in ``info``;
    a fixed grid gets a :class:`~rothe.stepping.controllers.FixedStepController`.

    Returns
    -------
    (controller, tol, loop_tau_min)
        ``tol`` None for a fixed grid; ``loop_tau_min`` the evolve loop's floor (1e-300 on a
        fixed grid: it never shrinks a step, a failed step stops the run).
    """
    if not isinstance(control, Adaptive):
        if stepper.steps is not None:
            controller = FixedStepController(stepper.steps)
        else:
            controller = FixedStepController.uniform(stepper.tau, stepper.n_steps)
        return controller, None, 1e-300
    tol = control.tol
    tau_min = 1e-10 * T if control.tau_min is None else control.tau_min
    tau_max = T if control.tau_max is None else control.tau_max
    if tau_max < stepper.tau:
        raise fail("tau_max", tau_max, f"must be >= the first step tau = {stepper.tau:g}")
    if tau_min > stepper.tau:
        raise fail("tau_min", tau_min, f"must be <= the first step tau = {stepper.tau:g}")
    controller = adaptive_controller(stepper, tol, stepper.tau, tau_min=tau_min, tau_max=tau_max)
    info.update(
        tol=tol,
        tau_min=tau_min,
        tau_max=tau_max,
        ratio_cap=stepper.max_ratio if math.isfinite(stepper.max_ratio) else None,
    )
    return controller, tol, tau_min


def describe_run(
    problem,
    stepper,
    *,
    solver_kind: str,
    solver: str,
    noise,
    adapt,
    store_fields: bool,
    linear_rtol: float,
    error_scale,
    meta,
    backend: dict | None = None,
):
    """What a run says about itself and what its checkpoint must match, for both backends:
    ``(info, arguments, controller, loop_tau_min)``.

    ``info`` is the trajectory's meta data (example, form, scheme, control, steps, data,
    lifting, solver, Lemma 3.2's bound, the start, the problem; the controller's tol and
    bounds; ``meta`` last); ``arguments`` the run's arguments a checkpoint is checked against
    (:func:`rothe.io.checkpoint.run_arguments`, the stepper's values after validation); the
    step controller built from ``stepper.control`` (:func:`rothe.eld.controllers.step_controller`)
    and the evolve loop's tau_min. ``backend`` (the PETSc backend: its name and processes)
    goes into both."""
    scheme, form, control, data = stepper.scheme, stepper.form, stepper.control, stepper.data_mode
    control_name = "adaptive" if isinstance(control, Adaptive) else "uniform"
    info = {
        "example": problem.name,
        "form": form.name,
        "scheme": scheme.name,
        "control": control_name,
        "tau": stepper.tau,
        "n_steps": stepper.n_steps,
        "data": data.name,
        "lifting": form.lifting,
        "solver": solver_kind,
        "step_bound": problem.step_bound(),
        "keep_every": stepper.keep_every,
        "start": scheme.describe()["start"],
        **(backend or {}),
        "problem": problem.describe(),
    }
    if isinstance(control, Given):
        info["control"] = "given steps"
    if noise is not None:
        info["noise"] = noise.describe()
    if adapt is not None:
        info["space"] = adapt.describe()  # the key of the outputs since issue 8
    controller, tol, loop_tau_min = step_controller(stepper, control, problem.T, info)
    tau_min, tau_max = info.get("tau_min"), info.get("tau_max")  # None on a fixed grid
    info.update(meta or {})
    arguments = run_arguments(
        form=form.name,
        scheme=scheme.name,
        control=control_name,
        tol=tol,
        tau=stepper.tau,
        steps=stepper.steps,
        data=data.name,
        lifting=form.lifting,
        solver=solver,
        newton=asdict(stepper.newton),
        noise=None if noise is None else noise.describe(),
        store_fields=store_fields,
        keep_every=stepper.keep_every,
        linear_rtol=linear_rtol,
        tau_min=tau_min,
        tau_max=tau_max,
        start=scheme.describe()["start"],
        error_scale=error_scale,
        **({} if adapt is None else {"adapt": adapt.describe()}),
        **(backend or {}),
    )
    return info, arguments, controller, loop_tau_min


def checkpoint_where(traj, state) -> dict:
    """Where a run of elastodynamics stands, for a checkpoint's ``where``: the accepted steps
    of its trajectory and the state's time (t, and s = t: the loop's position) and index j.
    The same for run_eld on either backend and for coupled runs."""
    return {
        "accepted_steps": traj.stats.accepted_steps,
        "s": float(state.t),
        "t": float(state.t),
        "j": int(state.j),
    }
