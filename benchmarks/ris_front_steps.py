"""Where the steps of ris-front's residual controls go: every attempt logged, for a time slice.

    python benchmarks/ris_front_steps.py CONTROL SECONDS fixed|adapt [N] [TOL]

Runs :func:`rothe.ris.examples.example_front` (N x N, default 16; the cell rule; ``adapt``:
ris-front's --adapt-space defaults space_tol 3, adapt_every 4, refine_band 0.08) with CONTROL
(order2, regime, adaptive) at TOL (default 1e-4, first step 0.02) for SECONDS of wall time,
wrapping the controller's ``decide`` to log every attempt (s, t, tau, accepted, I1, I2, the
regime of :func:`rothe.ris.controllers.step_regime`, dist at both ends, Newton iterations).
Prints the attempts per (regime, accepted), the rejections by (regime of the accepted step
before, regime of the rejected attempt), Newton iterations of accepted and rejected attempts,
the number of viscous-jump events (maximal runs of accepted jump steps) and the attempts and
Newton iterations needed to reach t = 0.1, 0.2, 0.3, 0.35. The log goes to
/tmp/ris_front_steps_<control>_<fixed|adapt>.json. Issue 18, item 0.
"""

from __future__ import annotations

import collections
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from rothe.fem.adapt import SpaceAdaptivity  # noqa: E402
from rothe.ris import examples  # noqa: E402
from rothe.ris import run as runmod  # noqa: E402
from rothe.ris.controllers import Order2, Regime, step_regime  # noqa: E402
from rothe.stepping.controllers import Adaptive  # noqa: E402


class _Stop(Exception):
    pass


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    name, seconds, where = argv[0], float(argv[1]), argv[2]
    n = int(argv[3]) if len(argv) > 3 else 16
    tol = float(argv[4]) if len(argv) > 4 else 1e-4
    control = {"order2": Order2, "regime": Regime, "adaptive": Adaptive}[name](tol, tau=0.02)
    log, t0 = [], time.perf_counter()
    build = runmod.build_controller

    def logged(control, grid=None):
        c = build(control, grid)
        decide = c.decide

        def wrapped(result):
            d = decide(result)
            log.append(
                dict(
                    s=result.state.s,
                    t=result.state.t,
                    tau=result.tau,
                    acc=d.accept,
                    I1=result.I1,
                    I2=result.I2,
                    reg=step_regime(result),
                    d0=result.dist_start,
                    d1=result.dist_end,
                    newton=result.counters.get("newton_iterations", 0),
                )
            )
            if time.perf_counter() - t0 > seconds:
                raise _Stop
            return d

        c.decide = wrapped
        return c

    runmod.build_controller = logged
    p = examples.example_front(n, dirichlet=("right",), quadrature="consistent")
    adapt = SpaceAdaptivity(space_tol=3.0, adapt_every=4, refine_band=0.08)
    try:
        runmod.run_ris(p, control, adapt=adapt if where == "adapt" else None)
    except _Stop:
        pass
    except Exception as exc:  # the evolve loop wraps the stop: keep the log
        if not isinstance(exc.__context__, _Stop) and "_Stop" not in repr(exc):
            raise
    Path(f"/tmp/ris_front_steps_{name}_{where}.json").write_text(json.dumps(log))
    counts, after, newton = collections.Counter(), collections.Counter(), collections.Counter()
    prev = None
    for a in log:
        counts[(a["reg"], a["acc"])] += 1
        newton[a["acc"]] += a["newton"]
        if a["acc"]:
            prev = a["reg"]
        else:
            after[(prev, a["reg"])] += 1
    events, inside = 0, False
    for a in (a for a in log if a["acc"]):
        events += a["reg"] == "jump" and not inside
        inside = a["reg"] == "jump"
    print("attempts by (regime, accepted):", sorted(counts.items(), key=str))
    print("rejected by (regime before, regime of the attempt):", after.most_common())
    print("Newton iterations accepted / rejected:", newton[True], "/", newton[False])
    t = np.maximum.accumulate([a["t"] for a in log])
    cum = np.cumsum([a["newton"] for a in log])
    print(f"jump events {events}, t = {t[-1]:.4f}, attempts {len(log)}")
    for ts in (0.1, 0.2, 0.3, 0.35):
        i = int(np.searchsorted(t, ts))
        if i < len(t):
            print(f"t = {ts}: {i} attempts, {cum[i]} Newton iterations")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
