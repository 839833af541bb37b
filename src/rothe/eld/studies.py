"""Parameter studies on the manufactured solution: convergence in tau, and Theorem 4.5.

:func:`convergence_study` halves tau repeatedly and fits the order of the errors at T and of
their maxima over all steps (u, u' in L2, lambda in L2(Gamma_D)), for either scheme.
With P2 elements the manufactured solution is exact in space (:mod:`rothe.eld.examples`), so
the mesh cannot hide the temporal error however coarse it is.

:func:`perturbation_study` makes Theorem 4.5 visible: it perturbs the data of every step by
delta-sized noise (:class:`~rothe.eld.data.DataNoise`) and reports, for each tau and both forms,
the amplifications

    amp   = max_j ||lambda_pert^j - lambda^j||_{L2(Gamma_D)} / delta,
    amp_v = max_j ||v_pert^j - v^j||_{L2} / delta,   amp_u = max_j ||u_pert^j - u^j||_{L2} / delta.

Each datum is perturbed alone (targets ``G``, ``G_dot``, ``G_ddot``, ``F``), each with its own
delta-sized vector as in (4.6). The original form sees only G + theta and differences it
implicitly (xi ~ theta/tau, vartheta ~ theta/tau^2); noise in G_dot or G_ddot does not reach it
(amplification 0). Noise in F enters both forms identically.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from ..errors import RotheInputError, check_int, check_positive, fail
from ..fem.mesh import box
from ..parallel import Executor, Task
from ..stepping.controllers import Uniform
from .coupled_run import run_coupled
from .data import DEFAULT_DATA, NOISE_TARGETS, DataMode, DataNoise, as_data_mode
from .examples import mms_errors, mms_problem, tip_mass_problem
from .form import DEFAULT_FORM, Form, Original, Regularized, as_form
from .frequencies import modal_frequencies, pencil_frequencies
from .run import run_eld
from .scheme import DEFAULT_SCHEME, Scheme, as_scheme
from .stepper import uniform_steps

#: the forms of the perturbation study, by their names in its tables
FORMS = (Regularized(), Original())

#: most steps of the finest run of a convergence study (T / (tau0 / 2^halvings))
MAX_STUDY_STEPS = 10**6
#: largest noise of the perturbation study: the manufactured data G and F are of size about 1,
#: and Theorem 4.5 is about the response to perturbations small against the data (1e300 made
#: the data overflow and the factorization fail)
MAX_DELTA = 1.0


def check_halvings(name: str, halvings, tau0: float, T: float) -> int:
    """halvings >= 1 with at most MAX_STUDY_STEPS steps in the finest run."""
    halvings = check_int(name, halvings, minimum=1)
    tau0 = check_positive("tau0", tau0)
    T = check_positive("T", T)
    steps = T / tau0 * 2.0**halvings
    if steps > MAX_STUDY_STEPS:
        most = max(0, int(np.floor(np.log2(MAX_STUDY_STEPS * tau0 / T))))
        raise fail(
            name,
            halvings,
            f"must be <= {most} (the finest run would take {steps:.3g} "
            f"steps of tau0/2^{halvings}; at most {MAX_STUDY_STEPS:.0e})",
        )
    return halvings


def check_delta(name: str, delta) -> float:
    """A noise size 0 < delta <= MAX_DELTA (one line naming ``name``)."""
    delta = check_positive(name, delta)
    if delta > MAX_DELTA:
        raise fail(
            name,
            delta,
            f"must be <= {MAX_DELTA:g} (noise small against the data, which are of size about 1)",
        )
    return delta


def check_noise_targets(name: str, targets, allowed=NOISE_TARGETS) -> tuple[str, ...]:
    """Data to perturb: names of ``allowed`` (NOISE_TARGETS; COUPLED_TARGETS for the coupled
    study), as a comma-separated string or a sequence; at least one (an empty list gave
    StopIteration when the table was formatted)."""
    items = targets.split(",") if isinstance(targets, str) else list(targets)
    items = [str(t).strip() for t in items if str(t).strip()]
    if not items:
        shown = targets if isinstance(targets, str) else ""
        raise fail(name, shown, "must name at least one of " + ", ".join(allowed))
    for t in items:
        if t not in allowed:
            raise fail(name, t, "must be one of " + ", ".join(allowed))
    return tuple(dict.fromkeys(items))


def fitted_rate(taus, errors) -> float | None:
    """Least-squares slope of log(error) against log(tau) over the runs that completed (NaN: a
    run that failed); None if an error is not positive or fewer than two runs completed."""
    taus, errors = np.asarray(taus, float), np.asarray(errors, float)
    done = ~np.isnan(errors)
    e = errors[done]
    if done.sum() < 2 or not np.all(e > 0) or not np.all(np.isfinite(e)):
        return None
    return float(np.polyfit(np.log(taus[done]), np.log(e), 1)[0])


def convergence_run(
    form: Form,
    tau: float,
    *,
    n: int,
    degree: int,
    damping,
    rho: float,
    lam: float,
    mu: float,
    T: float,
    data: DataMode,
    scheme: Scheme,
    progress=False,
) -> dict:
    """One run of :func:`convergence_study` (a task: builds the problem itself): its row, with
    the problem's ``ndofs`` and ``damping`` description under ``"_problem"``."""
    problem, exact = mms_problem(n, degree, damping=damping, rho=rho, lam=lam, mu=mu, T=T)
    t0 = time.perf_counter()
    result = run_eld(
        problem, scheme=scheme, form=form, control=Uniform(tau), data=data, progress=progress
    )
    err = mms_errors(exact, result)
    traj = result.trajectory
    st = traj.stats
    return {
        "tau": tau,
        "steps": st.accepted_steps,
        "newton_iterations": st.newton_iterations,
        "backsolves": traj.meta["linear_solver"]["backsolves"],
        "seconds": time.perf_counter() - t0,
        **err,
        "_problem": {"ndofs": problem.space.ndofs, "damping": problem.damping.describe()},
    }


def check_uniform_runs(tau0: float, scheme: Scheme, data: DataMode, n, degree, **problem):
    """What every run of a study checks, once, before any run (or a cluster) starts: the
    manufactured problem (``n``, ``degree``, ``damping``, ``rho``, ``lam``, ``mu``, ``T``), the
    data mode with the scheme, and the largest step ``tau0`` (tau0/2^k divides T when tau0
    does, and Lemma 3.2's bound is hardest for tau0; named ``tau0``). Without it each run
    failed on its own after the cluster had started (issue 21)."""
    as_data_mode(data).check(scheme)
    built, _ = mms_problem(n, degree, **problem)
    try:
        uniform_steps(tau0, built.T, scheme, built.step_bound())
    except RotheInputError as exc:
        raise (exc.renamed("tau0") if exc.parameter == "tau" else exc) from None


def _problem_meta(results, build) -> dict:
    """ndofs and damping of the study's problem: from a run, else of the ELDProblem
    ``build()`` returns (all runs failed)."""
    for r in results:
        if isinstance(r.value, dict) and "_problem" in r.value:
            return r.value["_problem"]
    problem = build()
    return {"ndofs": problem.space.ndofs, "damping": problem.damping.describe()}


_ERRORS = ("u_l2", "u_h1", "v_l2", "v_h1", "lam_l2", "u_l2_max", "v_l2_max", "lam_l2_max")


def convergence_study(
    form: Form = DEFAULT_FORM,
    *,
    tau0: float = 0.1,
    halvings: int = 5,
    n: int = 4,
    degree: int = 2,
    damping=None,
    rho: float = 1.0,
    lam: float = 2.0,
    mu: float = 1.0,
    T: float = 1.0,
    data: DataMode = DEFAULT_DATA,
    scheme: Scheme = DEFAULT_SCHEME,
    progress: bool = False,
    executor=None,
) -> dict:
    """Errors at T of u, v (L2, H1) and lambda (L2(Gamma_D)), and the maxima over the steps of
    the L2 errors, for tau0 / 2^k, k = 0..halvings.

    The runs are independent tasks of ``executor`` (:class:`rothe.parallel.Executor`; default:
    one after another in this process). A run that fails is a row with its ``status`` and NaN
    errors; the orders are fitted over the completed runs.

    Parameters
    ----------
    form : Regularized or Original
    tau0 : float
        The largest step.
    halvings : int
        Times tau0 is halved.
    n, degree : int
        The manufactured problem's mesh and element (:func:`rothe.eld.mms_problem`).
    damping, rho, lam, mu, T
        Its damping, material and end time.
    data : DataMode
    scheme : ImplicitEuler or BDF2
    progress : bool
    executor : rothe.parallel.Executor, optional

    Returns
    -------
    dict
        ``tau``, ``error_u``, ``error_v``, ``error_lam`` and their maxima over the steps
        ``error_*_max``, H1 errors, fitted ``rate_*``, the ``rows`` of the runs.
    """
    form, scheme = as_form(form), as_scheme(scheme)
    tau0 = check_positive("tau0", tau0)
    halvings = check_halvings("halvings", halvings, tau0, T)
    taus = [tau0 / 2**k for k in range(halvings + 1)]
    check_uniform_runs(tau0, scheme, data, n, degree, damping=damping, rho=rho, lam=lam, mu=mu, T=T)
    # a run's own progress only in this process (a worker's stderr is not the user's)
    inner_progress = progress if executor is None or executor.in_process else False
    common = dict(
        n=n,
        degree=degree,
        damping=damping,
        rho=rho,
        lam=lam,
        mu=mu,
        T=T,
        data=data,
        scheme=scheme,
        progress=inner_progress,
    )
    tasks = [
        Task(
            f"{form.name} tau={tau:g}",
            convergence_run,
            {"form": form, "tau": tau, **common},
            cost=1 / tau,
        )
        for tau in taus
    ]
    results = (executor or Executor(1, progress=False)).map(tasks)
    meta = _problem_meta(
        results,
        lambda: mms_problem(n, degree, damping=damping, rho=rho, lam=lam, mu=mu, T=T)[0],
    )
    rows = []
    for tau, res in zip(taus, results, strict=True):
        if res.completed:
            rows.append({k: v for k, v in res.value.items() if k != "_problem"})
        else:
            rows.append(
                {
                    "tau": tau,
                    "status": f"{res.status}: {res.message}",
                    **{f"error_{x}": float("nan") for x in _ERRORS},
                }
            )
    out = {
        "example": "eld-mms",
        "form": form.name,
        "scheme": scheme.name,
        "n": n,
        "degree": degree,
        "data": data.name,
        "lifting": form.lifting,
        "ndofs": meta["ndofs"],
        "damping": meta["damping"],
        "tau": taus,
        "error_u": [r["error_u_l2"] for r in rows],
        "error_u_h1": [r["error_u_h1"] for r in rows],
        "error_v": [r["error_v_l2"] for r in rows],
        "error_v_h1": [r["error_v_h1"] for r in rows],
        "error_lam": [r["error_lam_l2"] for r in rows],
        "error_u_max": [r["error_u_l2_max"] for r in rows],
        "error_v_max": [r["error_v_l2_max"] for r in rows],
        "error_lam_max": [r["error_lam_l2_max"] for r in rows],
        "lam_norm": "L2(Gamma_D)",
        "rows": rows,
    }
    for key in ("u", "u_h1", "v", "v_h1", "lam", "u_max", "v_max", "lam_max"):
        out[f"rate_{key}"] = fitted_rate(taus, out[f"error_{key}"])
    return out


def format_convergence_table(study: dict) -> str:
    """The convergence study as a table: errors at T and maxima per tau, fitted orders."""
    head = (
        f"{'tau':>9} {'steps':>6} {'newton':>7} {'|u-u_h| L2':>11} {'H1':>10} "
        f"{'|v-v_h| L2':>11} {'H1':>10} {'|lam| L2(G_D)':>13} {'max_j u':>10} "
        f"{'max_j v':>10} {'max_j lam':>10} {'seconds':>8}"
    )
    lines = [
        f"eld-mms, scheme {study.get('scheme', 'euler')}, form {study['form']}, "
        f"P{study['degree']}, n = {study['n']} ({study['ndofs']} dofs), data by "
        f"{study['data']}; errors at T and maxima over the steps",
        head,
        "-" * len(head),
    ]
    for r in study["rows"]:
        if "steps" not in r:  # a run that failed
            lines.append(f"{r['tau']:>9.5f}  {r['status']}")
            continue
        lines.append(
            f"{r['tau']:>9.5f} {r['steps']:>6d} {r['newton_iterations']:>7d} "
            f"{r['error_u_l2']:>11.3e} {r['error_u_h1']:>10.3e} {r['error_v_l2']:>11.3e} "
            f"{r['error_v_h1']:>10.3e} {r['error_lam_l2']:>13.3e} "
            f"{r['error_u_l2_max']:>10.3e} {r['error_v_l2_max']:>10.3e} "
            f"{r['error_lam_l2_max']:>10.3e} {r['seconds']:>8.2f}"
        )
    r = {k: "n/a" if v is None else f"{v:.3f}" for k, v in study.items() if k.startswith("rate_")}
    lines.append(
        f"fitted orders at T: u {r['rate_u']} (H1 {r['rate_u_h1']}), "
        f"v {r['rate_v']} (H1 {r['rate_v_h1']}), "
        f"lambda {r['rate_lam']}; max over steps: u {r['rate_u_max']}, "
        f"v {r['rate_v_max']}, lambda {r['rate_lam_max']}"
    )
    return "\n".join(lines)


def _amplifications(problem, base, pert, delta: float) -> tuple[float, float, float]:
    c, M = problem.constraint, problem.M

    def l2(w):
        return float(np.sqrt(max(w @ (M @ w), 0.0)))

    amp = max(c.l2_norm(a - b) for a, b in zip(pert["lam"], base["lam"], strict=True)) / delta
    amp_v = max(l2(a - b) for a, b in zip(pert["v"], base["v"], strict=True)) / delta
    amp_u = max(l2(a - b) for a, b in zip(pert["u"], base["u"], strict=True)) / delta
    return amp, amp_v, amp_u


def perturbation_run(
    form: Form,
    tau: float,
    *,
    delta: float,
    targets,
    n: int,
    degree: int,
    damping,
    seed: int,
    T: float,
    scheme: Scheme,
    rho: float = 1.0,
    progress=False,
) -> dict:
    """One (tau, form) of :func:`perturbation_study` (a task: builds the problem itself): the
    unperturbed run and one perturbed run per target; the amplifications by target."""
    problem, _ = mms_problem(n, degree, damping=damping, rho=rho, T=T)
    options = dict(scheme=scheme, form=form, control=Uniform(tau), progress=progress)
    base = run_eld(problem, **options).trajectory
    out = {"_problem": {"ndofs": problem.space.ndofs, "damping": problem.damping.describe()}}
    for target in targets:
        pert = run_eld(problem, noise=DataNoise(delta, target, seed), **options).trajectory
        out[target] = _amplifications(problem, base, pert, delta)
    return out


def perturbation_study(
    taus=(0.1, 0.05, 0.02, 0.01, 0.005, 0.002, 0.001),
    *,
    delta: float = 1e-6,
    targets=("G", "G_dot", "G_ddot", "F"),
    forms=FORMS,
    n: int = 6,
    degree: int = 1,
    damping=None,
    seed: int = 0,
    T: float = 1.0,
    scheme: Scheme = DEFAULT_SCHEME,
    rho: float = 1.0,
    progress: bool = False,
    executor=None,
) -> dict:
    """Amplification of delta-noise in each datum alone (G, G_dot, G_ddot, F) for each tau and
    form (``forms``: Regularized and Original objects; the tables name them by ``form.name``).

    Returns ``{"tau": [...], "delta": delta, "<target>": table, ...}`` where each table holds
    ``amp_<form>`` (multiplier), ``amp_v_<form>``, ``amp_u_<form>`` (lists over tau) and the
    fitted slopes ``slope_<name>`` (None where the amplification is 0: the original form does
    not use G_dot, G_ddot); the amplifications under noise in G are repeated at the top level
    as ``amp_regularized``, ``amp_original``, ...

    Each (tau, form) is an independent task of ``executor`` (:class:`rothe.parallel.Executor`;
    default: one after another in this process). A (tau, form) whose runs fail gets NaN
    amplifications and is listed under ``"failed"``.

    Parameters
    ----------
    taus : sequence of float
        The step sizes.
    delta : float
        The size of the noise.
    targets : sequence of str
        The data perturbed, each alone.
    forms : sequence of Form
    n, degree : int
        The mesh of :func:`mms_problem`.
    damping : Damping, optional
    seed : int
        The noise's seed.
    T : float
    scheme : Scheme
    rho : float
        The density of :func:`mms_problem`.
    progress : bool
    executor : Executor, optional

    Returns
    -------
    dict
        As above.
    """
    # a run's own progress only in this process (a worker's stderr is not the user's)
    inner_progress = progress if executor is None or executor.in_process else False
    runs = _noise_runs(
        perturbation_run,
        forms,
        taus,
        targets,
        NOISE_TARGETS,
        executor,
        delta=delta,
        seed=seed,
        scheme=scheme,
        n=n,
        degree=degree,
        damping=damping,
        T=T,
        rho=rho,
        progress=inner_progress,
    )
    meta = _problem_meta(
        runs.results, lambda: mms_problem(n, degree, damping=damping, rho=rho, T=T)[0]
    )
    out = {
        "example": "eld-mms",
        "scheme": runs.scheme.name,
        "n": n,
        "degree": degree,
        "ndofs": meta["ndofs"],
        "targets": list(runs.targets),
        "damping": meta["damping"],
        "tau": runs.taus,
        "delta": runs.delta,
        "seed": runs.seed,
        "norms": {"lam": "L2(Gamma_D)", "v": "L2(Omega)", "u": "L2(Omega)"},
    }
    tables = runs.tables(out)
    if "G" in tables:
        for form in (f.name for f in runs.forms):
            out[f"amp_{form}"] = tables["G"][f"amp_{form}"]
            out[f"amp_v_{form}"] = tables["G"][f"amp_v_{form}"]
            out[f"amp_u_{form}"] = tables["G"][f"amp_u_{form}"]
    out["seconds"] = time.perf_counter() - runs.t0
    return out


@dataclass(frozen=True)
class NoiseRuns:
    """The (tau, form) runs of a perturbation study, validated and done (:func:`_noise_runs`):
    the checked ``forms``, ``taus``, ``targets``, ``delta``, ``seed``, ``scheme``, the ``tasks``,
    their ``results`` (in task order) and ``t0``, the start time of the runs."""

    forms: tuple
    taus: list
    targets: tuple
    delta: float
    seed: int
    scheme: object
    tasks: list
    results: list
    t0: float

    def tables(self, out: dict) -> dict:
        """:func:`_amplification_tables` of these runs, put into ``out``."""
        names = [f.name for f in self.forms]
        return _amplification_tables(out, self.tasks, self.results, self.targets, names)


def _noise_runs(
    run, forms, taus, targets, allowed, executor, *, delta, seed, scheme, **kwargs
) -> NoiseRuns:
    """The (tau, form) tasks of a perturbation study, validated and run: ``run(form, tau,
    delta=, targets=, seed=, scheme=, **kwargs)`` for every tau and form (``allowed``: the
    targets the study knows)."""
    forms = tuple(as_form(f) for f in forms)
    scheme = as_scheme(scheme)
    taus = [check_positive("taus", t) for t in taus]
    delta = check_delta("delta", delta)
    targets = check_noise_targets("targets", targets, allowed)
    seed = check_int("seed", seed, minimum=0)
    tasks = [
        Task(
            f"{form.name} tau={tau:g}",
            run,
            dict(
                form=form, tau=tau, delta=delta, targets=targets, seed=seed, scheme=scheme, **kwargs
            ),
            cost=(1 + len(targets)) / tau,
        )
        for tau in taus
        for form in forms
    ]
    t0 = time.perf_counter()
    results = (executor or Executor(1, progress=False)).map(tasks)
    return NoiseRuns(forms, taus, targets, delta, seed, scheme, tasks, results, t0)


def _amplification_tables(out: dict, tasks, results, targets, names) -> dict:
    """The tables of a perturbation study from its (tau, form) tasks' results (each a dict
    target -> (amp, amp_v, amp_u)): per target ``amp_<form>, amp_v_<form>, amp_u_<form>`` over
    tau and their fitted slopes, put into ``out`` under the target's name; the (tau, form) whose
    runs failed get NaN and are listed under ``out["failed"]``. Returns the tables."""
    tables = {
        t: {f"{k}_{f}": [] for k in ("amp", "amp_v", "amp_u") for f in names} for t in targets
    }
    nan = (float("nan"),) * 3
    failed = []
    for task, res in zip(tasks, results, strict=True):
        form = task.kwargs["form"].name
        if not res.completed:
            failed.append(
                {"tau": task.kwargs["tau"], "form": form, "status": f"{res.status}: {res.message}"}
            )
        for target in targets:
            amp, amp_v, amp_u = res.value[target] if res.completed else nan
            tables[target][f"amp_{form}"].append(amp)
            tables[target][f"amp_v_{form}"].append(amp_v)
            tables[target][f"amp_u_{form}"].append(amp_u)
    taus = out["tau"]
    for target, table in tables.items():
        for name in list(table):
            table[f"slope_{name}"] = fitted_rate(taus, table[name])
        out[target] = table
    if failed:
        out["failed"] = failed
    return tables


# -- Theorem 4.5 with couplings: noise in the component's outputs (issue 19) ----------------------

#: the coupled study's targets: noise in the component's coordinates where they enter the
#: coupling data, each alone: g = G + Gamma (q + theta), g' = G_dot + Gamma (p + xi),
#: g'' = G_ddot + Gamma (p' + vartheta) (:class:`~rothe.eld.coupled_run.CoupledStepper`)
COUPLED_TARGETS = ("q", "q_dot", "q_ddot")
#: the coupled study's tip part (the coupling B u = q of :func:`tip_mass_problem`)
COUPLED_PART = "right"


def coupled_perturbation_run(
    form: Form,
    tau: float,
    *,
    delta: float,
    targets,
    n: int,
    degree: int,
    damping,
    seed: int,
    T: float,
    scheme: Scheme,
    rho: float = 1.0,
    progress=False,
) -> dict:
    """One (tau, form) of :func:`coupled_perturbation_study` (a task: builds the system
    itself): the unperturbed coupled run and one perturbed run per target; per target
    (amp, amp_v, amp_u) = max_j of |R_pert - R|, |p_pert - p|, |q_pert - q| over delta, with R
    the reaction (resultant of lambda) on the coupled part and q, p the tip mass's coordinates
    and velocity (Euclidean norms)."""
    system = tip_mass_problem(n, degree, rho=rho, T=T, damping=damping).system
    options = dict(scheme=scheme, form=form, control=Uniform(tau))
    base = run_coupled(system, **options)
    r = base.stepper.r
    keys = (f"reaction_{COUPLED_PART}", "p", "q")
    out = {
        "_problem": {
            "ndofs": system.body.space.ndofs,
            "damping": system.body.damping.describe(),
        }
    }
    for target in targets:
        slot = COUPLED_TARGETS.index(target)

        def noise(j, slot=slot):
            # the noise of step j depends only on (seed, j): the same in both forms
            w = delta * np.random.default_rng([seed, j]).uniform(-1.0, 1.0, r)
            return tuple(w if i == slot else None for i in range(3))

        pert = run_coupled(system, noise=noise, **options)
        out[target] = tuple(
            float(
                np.linalg.norm(
                    np.asarray(pert.trajectory[k]) - np.asarray(base.trajectory[k]), axis=1
                ).max()
            )
            / delta
            for k in keys
        )
    return out


def coupled_perturbation_study(
    taus=(0.02, 0.01, 0.005, 0.0025, 0.00125, 0.000625),
    *,
    delta: float = 1e-6,
    targets=COUPLED_TARGETS,
    forms=FORMS,
    n: int = 2,
    degree: int = 2,
    damping=None,
    seed: int = 0,
    T: float = 0.2,
    scheme: Scheme = DEFAULT_SCHEME,
    rho: float = 1.0,
    progress: bool = False,
    executor=None,
) -> dict:
    """Theorem 4.5 with a coupling: noise of size delta in the coordinates of a component as
    the body sees them (the tip mass of :func:`~rothe.eld.examples.tip_mass_problem`, B u = q
    on ``right``, started in its first axial mode), each target alone (``q``: theta in g,
    ``q_dot``: xi in g', ``q_ddot``: vartheta in g''), for each tau and form.

    The original form sees only g = G + Gamma (q + theta) and differences it (its xi ~ theta /
    tau, vartheta ~ theta / tau^2): the reaction's amplification grows like tau^-2 and the tip
    velocity's like tau^-1; the regularized form takes q, p, p' as separate data and stays
    bounded. Noise in q_dot, q_ddot does not reach the original form (amplification 0); in the
    regularized form noise in q_dot enters through the damping only (0 without damping).

    Returns the dict of :func:`perturbation_study` (``tau``, per target ``amp_<form>`` (the
    reaction on ``right``), ``amp_v_<form>`` (the tip velocity p), ``amp_u_<form>`` (the tip
    displacement q) and their fitted slopes) with ``columns`` naming the three quantities.

    Parameters
    ----------
    taus : sequence of float
    delta : float
    targets : sequence of str
        Names of COUPLED_TARGETS.
    forms : sequence of Form
    n, degree : int
        The strip of :func:`tip_mass_problem` (n cells across).
    damping : Damping, optional
        The body's damping (default none).
    seed : int
    T : float
    scheme : Scheme
    rho : float
        The bar's density.
    progress : bool
        Unused (coupled runs have no progress bar); for the commands' common call.
    executor : Executor, optional
    """
    runs = _noise_runs(
        coupled_perturbation_run,
        forms,
        taus,
        targets,
        COUPLED_TARGETS,
        executor,
        delta=delta,
        seed=seed,
        scheme=scheme,
        n=n,
        degree=degree,
        damping=damping,
        T=T,
        rho=rho,
    )
    meta = _problem_meta(
        runs.results, lambda: tip_mass_problem(n, degree, rho=rho, T=T, damping=damping).system.body
    )
    out = {
        "example": "eld-tip-mass",
        "scheme": runs.scheme.name,
        "n": n,
        "degree": degree,
        "ndofs": meta["ndofs"],
        "targets": list(runs.targets),
        "damping": meta["damping"],
        "T": T,
        "tau": runs.taus,
        "delta": runs.delta,
        "seed": runs.seed,
        "columns": ["R", "p", "q"],
        "norms": {
            "lam": f"|reaction on {COUPLED_PART!r}|",
            "v": "|p| (tip velocity)",
            "u": "|q| (tip displacement)",
        },
    }
    runs.tables(out)
    out["seconds"] = time.perf_counter() - runs.t0
    return out


_WHAT = {
    "G": "noise in G alone (u_2 = B^- G in the regularized form; G in the original form)",
    "G_dot": "noise in G_dot alone (v_2 in the regularized form; unused by the original form)",
    "G_ddot": "noise in G_ddot alone (w_2 in the regularized form; unused by the original form)",
    "F": "noise in F (both forms alike)",
    "q": "noise theta in the tip's coordinates q as the body sees them (g = G + Gamma (q + theta))",
    "q_dot": "noise xi in q' (g' in the regularized form, through the damping; unused by the "
    "original form)",
    "q_ddot": "noise vartheta in q'' (g'' in the regularized form; unused by the original form)",
}


def format_perturbation_table(study: dict) -> str:
    """The perturbation study as a table per datum: amplifications per tau and form, slopes."""
    lines = []
    present = [t for t in NOISE_TARGETS + COUPLED_TARGETS if t in study]
    first = study[present[0]]
    forms = [f.name for f in FORMS if f"amp_{f.name}" in first]
    col_lam, col_v, col_u = study.get("columns", ("lam", "v", "u"))
    for target in present:
        table = study[target]
        lines.append(
            f"scheme {study.get('scheme', 'euler')}, {_WHAT[target]}, delta = "
            f"{study['delta']:g}; max_j |x_pert - x| / delta"
        )
        head = f"{'tau':>8}"
        for f in forms:
            short = f[:3]
            head += (
                f" {col_lam + ' ' + short:>11} {col_v + ' ' + short:>10} {col_u + ' ' + short:>10}"
            )
        lines += [head, "-" * len(head)]
        for i, tau in enumerate(study["tau"]):
            line = f"{tau:>8.4f}"
            for f in forms:
                line += (
                    f" {table[f'amp_{f}'][i]:>11.3e} {table[f'amp_v_{f}'][i]:>10.3e}"
                    f" {table[f'amp_u_{f}'][i]:>10.3e}"
                )
            lines.append(line)
        slopes = ", ".join(
            f"{k[len('slope_') :]} " + ("n/a" if v is None else f"{v:+.2f}")
            for k, v in table.items()
            if k.startswith("slope_")
        )
        lines.append(f"log-log slopes in tau: {slopes}")
        lines.append("")
    for f in study.get("failed", ()):
        lines.append(f"tau = {f['tau']:g}, {f['form']}: {f['status']}")
    return "\n".join(lines).rstrip()


# -- the tip-mass bar's first frequency in h and tau (issue 19) ----------------------------------


#: the tip-mass bar of the study: length and height (and width in 3D) of the strip or the box
TIP_MASS_BAR = (1.0, 0.25)


def tip_mass_bar(n: int, dim: int = 2):
    """The study's 3D bar [0, 1] x [0, 0.25]^2 with n cubes across and 4n along (six
    tetrahedra each; parts ``left`` .. ``back``: :func:`rothe.fem.mesh.box`); None in 2D (the
    strip of :func:`tip_mass_problem`, n cells across)."""
    if dim == 2:
        return None
    length, height = TIP_MASS_BAR
    return box(max(1, round(n * length / height)), n, n, length, height, height)


def tip_mass_frequency_run(
    n: int,
    tau: float,
    *,
    degree: int,
    scheme: Scheme,
    form: Form,
    mass: float,
    T: float,
    dim: int = 2,
    modes: int = 3,
) -> dict:
    """One (n, tau) of :func:`tip_mass_study` (a task: builds the bar itself): the first
    ``modes`` axial angular frequencies of the analytic bar, of the semi-discrete system and
    measured from the run started in their sum (the zero crossings of the modal coordinates
    c_k = phi_k^T M x, recorded per state as ``watch`` rows: no fields kept)."""
    example = tip_mass_problem(n, degree, mass=mass, T=T, mesh=tip_mass_bar(n, dim), modes=modes)
    res = run_coupled(
        example.system, scheme=scheme, form=form, control=Uniform(tau), watch=example.watch
    )
    traj = res.trajectory
    return {
        "ndofs": example.system.body.space.ndofs,
        "analytic": example.analytic[:modes].tolist(),
        "discrete": example.discrete[:modes].tolist(),
        "measured": modal_frequencies(traj["t"], example.modal_coordinates(traj)),
        # the same frequencies from the tip's q_x alone (what an experimenter records)
        "measured_tip": pencil_frequencies(traj["t"], np.asarray(traj["q"])[:, 0], modes),
    }


def tip_mass_study(
    ns=(1, 2, 4),
    taus=(0.01, 0.005, 0.0025),
    *,
    degree: int = 2,
    scheme: Scheme = DEFAULT_SCHEME,
    form: Form = DEFAULT_FORM,
    mass: float = 0.25,
    T: float = 2.0,
    dim: int = 2,
    modes: int = 3,
    progress: bool = False,
    executor=None,
) -> dict:
    """The first axial frequencies of the tip-mass bar (:func:`tip_mass_problem`: P1/P2 strip
    with n cells across -- or with ``dim=3`` the box bar 1 x 0.25 x 0.25 with n x n cubes
    across, :func:`tip_mass_bar` --, clamped on ``left``, the mass on ``right`` by B u = q,
    started in the sum of its first ``modes`` axial modes) against the analytic
    bar-with-tip-mass values (beta L tan(beta L) = rho A L / m; A = 0.25 per unit thickness in
    2D, 0.0625 in 3D), for every mesh n and step tau. Each frequency is measured from the run:
    the zero crossings of its modal coordinate c_k = phi_k^T M x (the run's states projected
    M-orthogonally on the discrete mode; a linear scheme steps each c_k on its own, so the
    measured w_k carries the scheme's period error at w_k tau and nothing of the other modes).

    The measured error w_run / w - 1 splits into the space error w_h / w - 1 of the semi-
    discrete system (no tau: :func:`~rothe.eld.coupled_step.coupled_modes`; order 2p in h for
    P_p elements, the Rayleigh quotient's squared energy error) and the time error w_run / w_h
    - 1 (the scheme's phase error, order 2 for BDF2 and for implicit Euler alike: Euler's
    first-order error is in the amplitude, arg 1/(1 - i w tau) = w tau - (w tau)^3/3 + ...; plus
    the zero crossings' linear interpolation, order 2).

    Returns ``{"n": [...], "tau": [...], "ndofs", "analytic", "discrete": per n, "measured":
    [n][tau], "error": [n][tau] (measured against analytic), "error_space": per n, "error_time":
    [n][tau], "order_h"`` (fitted slope of the space error in h ~ 1/n), ``"order_tau"`` (fitted
    slope of the time error at the finest n)``}`` -- all of the first mode, as before -- and
    per mode k (last index): ``"analytic_modes"`` [k], ``"discrete_modes"`` [n][k],
    ``"measured_modes"``, ``"error_modes"``, ``"error_time_modes"`` [n][tau][k],
    ``"error_space_modes"`` [n][k], ``"order_h_modes"``, ``"order_tau_modes"`` [k], and
    ``"measured_tip_modes"`` [n][tau][k], the frequencies of the tip's q_x alone
    (:func:`~rothe.eld.frequencies.pencil_frequencies`, the matrix pencil); a failed
    (n, tau) gets NaN and is listed under ``"failed"``.

    Parameters
    ----------
    ns : sequence of int
        Cells across the strip (h = height / n).
    taus : sequence of float
    degree : int
    scheme : Scheme
    form : Form
    mass : float
        The tip mass (the bar's own mass is 0.25 in 2D, 0.0625 in 3D).
    T : float
        End time (2: about 2.7 periods in 2D).
    dim : int
        2 (the plane-stress strip) or 3 (the box bar, nu = 0: both are exact 1D bars axially).
    modes : int
        K >= 1, the axial modes excited and measured (:func:`tip_mass_problem`'s ``modes``).
    progress : bool
        Unused (coupled runs have no progress bar); for the commands' common call.
    executor : Executor, optional
    """
    ns = [check_int("ns", n, minimum=1) for n in ns]
    taus = [check_positive("taus", t) for t in taus]
    if len(ns) < 2 and len(taus) < 2:
        raise fail("ns", ns, "needs two meshes or two step sizes (with taus) to fit an order")
    if dim not in (2, 3):
        raise fail("dim", dim, "must be 2 or 3")
    modes = check_int("modes", modes, minimum=1)
    scheme, form = as_scheme(scheme), as_form(form)
    options = dict(degree=degree, scheme=scheme, form=form, mass=mass, T=T, dim=dim, modes=modes)
    tasks = [
        Task(
            f"n={n} tau={tau:g}",
            tip_mass_frequency_run,
            dict(n=n, tau=tau, **options),
            cost=n**dim / tau,
        )
        for n in ns
        for tau in taus
    ]
    t0 = time.perf_counter()
    results = (executor or Executor(1, progress=False)).map(tasks)
    nan = float("nan")
    rows = {n: {} for n in ns}
    failed = []
    for task, res in zip(tasks, results, strict=True):
        n, tau = task.kwargs["n"], task.kwargs["tau"]
        if res.completed:
            rows[n][tau] = res.value
        else:
            failed.append({"n": n, "tau": tau, "status": f"{res.status}: {res.message}"})

    def first(n, key):
        return next((r[key] for r in rows[n].values()), nan)

    none = [nan] * modes
    analytic_k = np.array(next((r["analytic"] for n in ns for r in rows[n].values()), none))
    discrete_k = np.array([first(n, "discrete") if rows[n] else none for n in ns])
    measured_k = np.array(
        [[rows[n].get(tau, {}).get("measured", none) for tau in taus] for n in ns], dtype=float
    )
    measured_tip = np.array(
        [[rows[n].get(tau, {}).get("measured_tip", none) for tau in taus] for n in ns],
        dtype=float,
    )
    analytic = float(analytic_k[0])
    discrete = discrete_k[:, 0].tolist()
    measured = measured_k[:, :, 0].tolist()
    out = {
        "example": "eld-tip-mass",
        "dim": dim,
        "degree": degree,
        "scheme": scheme.name,
        "form": form.name,
        "mass": mass,
        "T": T,
        "n": ns,
        "tau": taus,
        "ndofs": [first(n, "ndofs") for n in ns],
        "analytic": analytic,
        "discrete": discrete,
        "measured": measured,
        "error": [[m / analytic - 1 for m in row] for row in measured],
        "error_space": [d / analytic - 1 for d in discrete],
        "error_time": [[m / d - 1 for m in row] for row, d in zip(measured, discrete, strict=True)],
    }
    # the space error decreases like h^(2p) = n^(-2p): the slope in h = 1/n
    out["order_h"] = fitted_rate([1.0 / n for n in ns], np.abs(out["error_space"]))
    out["order_tau"] = fitted_rate(taus, np.abs(out["error_time"][-1]))
    out.update(
        modes=modes,
        analytic_modes=analytic_k.tolist(),
        discrete_modes=discrete_k.tolist(),
        measured_modes=measured_k.tolist(),
        error_modes=(measured_k / analytic_k - 1).tolist(),
        error_space_modes=(discrete_k / analytic_k - 1).tolist(),
        error_time_modes=(measured_k / discrete_k[:, None, :] - 1).tolist(),
        measured_tip_modes=measured_tip.tolist(),
    )
    out["order_h_modes"] = [
        fitted_rate([1.0 / n for n in ns], np.abs(discrete_k[:, k] / analytic_k[k] - 1))
        for k in range(modes)
    ]
    out["order_tau_modes"] = [
        fitted_rate(taus, np.abs(measured_k[-1, :, k] / discrete_k[-1, k] - 1))
        for k in range(modes)
    ]
    if failed:
        out["failed"] = failed
    out["seconds"] = time.perf_counter() - t0
    return out


def format_tip_mass_table(study: dict) -> str:
    """The tip-mass study as a table: per (n, tau) the measured first frequency and its error
    against the analytic value, split into space and time, then for every further measured
    mode k its error against the analytic value (``wk err``) and against the semi-discrete one
    (``wk time``); the fitted orders of every mode."""
    modes = study.get("modes", 1)
    analytic = ", ".join(f"{w:.8g}" for w in study.get("analytic_modes", [study["analytic"]]))
    header = (
        f"{'n':>4} {'dofs':>6} {'tau':>9} {'measured':>12} {'error':>10} {'space':>10} {'time':>10}"
    )
    for k in range(2, modes + 1):
        header += f" {f'w{k} err':>10} {f'w{k} time':>10}"
    lines = [
        f"eld-tip-mass, {study.get('dim', 2)}D, P{study['degree']}, {study['scheme']}, "
        f"{study['form']}, m = {study['mass']:g}: the first {modes} axial angular frequencies "
        f"measured from the runs (modal coordinates), analytic {analytic}",
        header,
    ]
    lines.append("-" * len(lines[-1]))
    for i, n in enumerate(study["n"]):
        for k, tau in enumerate(study["tau"]):
            line = (
                f"{n:>4} {study['ndofs'][i]:>6} {tau:>9.5f} {study['measured'][i][k]:>12.8g} "
                f"{study['error'][i][k]:>10.2e} {study['error_space'][i]:>10.2e} "
                f"{study['error_time'][i][k]:>10.2e}"
            )
            for m in range(1, modes):
                line += (
                    f" {study['error_modes'][i][k][m]:>10.2e}"
                    f" {study['error_time_modes'][i][k][m]:>10.2e}"
                )
            lines.append(line)

    def fmt(order):
        return "n/a" if order is None else f"{order:.2f}"

    lines.append(
        f"space error (semi-discrete w_h / w - 1): order {fmt(study['order_h'])} in h; "
        f"time error (w_run / w_h - 1) at n = {study['n'][-1]}: order "
        f"{fmt(study['order_tau'])} in tau"
    )
    if "measured_tip_modes" in study:
        tip = np.array(study["measured_tip_modes"], dtype=float)
        gap = np.abs(tip / np.array(study["measured_modes"], dtype=float) - 1)
        worst = np.nanmax(gap) if np.isfinite(gap).any() else math.nan
        lines.append(
            "the tip's q_x alone (matrix pencil) against the modal coordinates' crossings: "
            f"max |w_tip / w_run - 1| = {worst:.1e}"
        )
    for m in range(1, modes):
        lines.append(
            f"mode {m + 1}: space error order {fmt(study['order_h_modes'][m])} in h "
            f"(w_h / w - 1 = {', '.join(f'{e[m]:.2e}' for e in study['error_space_modes'])}); "
            f"time error order {fmt(study['order_tau_modes'][m])} in tau"
        )
    for f in study.get("failed", ()):
        lines.append(f"n = {f['n']}, tau = {f['tau']:g}: {f['status']}")
    return "\n".join(lines)
