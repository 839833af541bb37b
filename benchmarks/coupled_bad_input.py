"""Issue 19's "Bad input" on every ``rothe run eld-*`` command where it applies: a coupling on
a part that does not exist, a part also carrying traction or prescribed data, a component's
mass, interfaces whose meshes do not touch, cells without a material, a sensor point outside
the body. Each case runs as a separate ``rothe`` process on coarse meshes written by meshio
into a temporary folder; one line per case: the item, the command line, the exit status, the
number of stderr lines and the last one. A case is handled when it exits 2 with one line and
leaves no output folder, or, for the one case that is accepted, exits 0 (docs/coupling.md
Sec. 18 has the table)::

    PYTHONPATH=src python benchmarks/coupled_bad_input.py [CASE ...]
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import meshio
import numpy as np
from skfem import MeshTri

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from tests.conftest import write_gmsh_body  # noqa: E402  (the tests' gmsh writer)


def write_l_body(path, touch: float = -1.0):
    """The L-shaped body [0, 1]^2 minus [0.5, 1]^2: facets 'inlet' (x = 0), 'ends' (x = 1 and
    y = 1 with x > ``touch``; its centroid lies in the cut-out square) and 'wall'; cells
    'core'. With the default ``touch`` 'ends' shares the node (0, 1) with 'inlet'."""
    m = MeshTri.init_tensor(np.linspace(0, 1, 9), np.linspace(0, 1, 9))
    c = m.p[:, m.t].mean(axis=1)
    m = MeshTri(m.p, m.t[:, ~((c[0] > 0.5) & (c[1] > 0.5))])
    facets = m.facets[:, m.boundary_facets()]
    mid = m.p[:, facets].mean(axis=1)
    ends = np.isclose(mid[0], 1) | (np.isclose(mid[1], 1) & (mid[0] > touch))
    tags = np.where(np.isclose(mid[0], 0), 1, np.where(ends, 2, 3))
    cells = np.full(m.t.shape[1], 4)
    groups = {"inlet": [1, 1], "ends": [2, 1], "wall": [3, 1], "core": [4, 2]}
    meshio.Mesh(
        m.p.T,
        [("line", facets.T), ("triangle", m.t.T)],
        cell_data={"gmsh:physical": [tags, cells], "gmsh:geometrical": [tags, cells]},
        field_data={k: np.array(v) for k, v in groups.items()},
    ).write(path, file_format="gmsh22", binary=False)
    return path


def cases(d: Path) -> list:
    strip = write_gmsh_body(d / "strip.msh", nx=8, ny=2, length=1.0, height=0.25, split=0.5)
    far = write_gmsh_body(d / "far.msh", nx=8, ny=2, length=1.0, height=0.25, x0=1.5)
    near = write_gmsh_body(d / "near.msh", nx=8, ny=2, length=1.0, height=0.25, x0=1.0)
    box = write_gmsh_body(d / "box.msh", dim=3, nx=4, ny=1, length=1.0, height=0.25, split=0.5)
    ell, ell2 = write_l_body(d / "lshape.msh"), write_l_body(d / "lshape2.msh", touch=0.125)
    hard = ["--material", "hard:lam=2,mu=1"]
    two = ["--clamp", "inlet", "--load-part", "outlet"]
    return [
        # a coupling on a part that does not exist
        ("part", "eld-tip-mass", ["--tip", "nope"]),
        ("part", "eld-tip-mass", ["--mesh", strip, "--dirichlet", "inlet", "--tip", "nope"]),
        ("part", "eld-tmd", ["--tip", "nope"]),
        ("part", "eld-tmd", ["--base", "nope"]),
        ("part", "eld-tmd", ["--mesh", strip, "--base", "inlet", "--tip", "nope"]),
        ("part", "eld-control", ["--tip", "nope"]),
        ("part", "eld-control", ["--base", "nope"]),
        ("part", "eld-control", ["--mesh", strip, "--base", "nope", "--tip", "outlet"]),
        ("part", "eld-two-bodies", ["--interface", "nope,left"]),
        ("part", "eld-two-bodies", ["--interface", "right,nope"]),
        ("part", "eld-two-bodies", ["--mesh1", strip, "--mesh2", near, "--interface",
                                    "outlet,nope", *two]),
        # a part also carrying traction or prescribed data (or coupled twice)
        ("data", "eld-tip-mass", ["--tip", "left"]),
        ("data", "eld-tip-mass", ["--mesh", strip, "--dirichlet", "inlet,outlet", "--tip",
                                  "outlet"]),
        ("data", "eld-tmd", ["--base", "right", "--tip", "right"]),
        ("data", "eld-control", ["--base", "right", "--tip", "right"]),
        ("data", "eld-tmd", ["--mesh", strip, "--base", "inlet", "--tip", "inlet"]),
        ("data", "eld-control", ["--mesh", strip, "--base", "outlet", "--tip", "outlet"]),
        ("data", "eld-tmd", ["--mesh", ell, "--base", "inlet", "--tip", "ends"]),
        ("data", "eld-two-bodies", ["--clamp", "right"]),
        ("data", "eld-two-bodies", ["--load-part", "left"]),
        ("data", "eld-two-bodies", ["--mesh1", strip, "--mesh2", near, "--interface",
                                    "outlet,inlet", "--clamp", "inlet", "--load-part", "inlet"]),
        # a component's mass (the API's singular and non-symmetric M_q: docs/coupling.md)
        ("mass", "eld-tip-mass", ["--mass", "0"]),
        ("mass", "eld-tip-mass", ["--mass", "-1"]),
        ("mass", "eld-tmd", ["--mass-ratio", "0"]),
        ("mass", "eld-control", ["--base-mass", "0"]),
        # interfaces whose meshes do not touch
        ("touch", "eld-two-bodies", ["--mesh1", strip, "--mesh2", far, "--interface",
                                     "outlet,inlet", *two]),
        # cells without a material
        ("cells", "eld-pulse", ["--mesh", strip, "--dirichlet", "inlet", *hard, "--region",
                                "hard=core", "--no-adapt-space"]),
        ("cells", "eld-pulse", ["--mesh", strip, "--dirichlet", "inlet", *hard, "--region",
                                "hard=nope", "--no-adapt-space"]),
        ("cells", "eld-pulse", ["--mesh", strip, "--dirichlet", "inlet", "--material",
                                "steel:E=1,nu=0.2", "--no-adapt-space"]),
        ("cells", "eld-pulse", ["--mesh", strip, "--dirichlet", "inlet", "--region",
                                "hard=core", "--no-adapt-space"]),
        ("cells", "eld-pulse-3d", ["--mesh", box, "--dirichlet", "inlet", "--degree", "1", *hard,
                                   "--region", "hard=core", "--no-adapt-space"]),
        ("cells", "eld-beam", ["--mesh", box, "--dirichlet", "inlet", "--degree", "1", *hard,
                               "--region", "hard=core"]),
        ("cells", "eld-tip-mass", ["--mesh", strip, "--dirichlet", "inlet", "--tip", "outlet",
                                   *hard, "--region", "hard=core"]),
        ("cells", "eld-tip-mass", ["--mesh", strip, "--dirichlet", "inlet", "--tip", "outlet",
                                   "--material", "core:E=1,nu=0.2"]),
        ("cells", "eld-mms", ["--mesh", strip, *hard, "--region", "hard=core"]),
        ("cells", "eld-tmd", ["--mesh", strip, "--base", "inlet", "--tip", "outlet", *hard,
                              "--region", "hard=core"]),
        ("cells", "eld-control", ["--mesh", strip, "--base", "inlet", "--tip", "outlet", *hard,
                                  "--region", "hard=core"]),
        # a sensor point outside the body (eld-control's sensor at the tip part's centroid)
        ("sensor", "eld-control", ["--mesh", ell, "--base", "inlet", "--tip", "ends"]),
        ("sensor", "eld-control", ["--mesh", ell2, "--base", "inlet", "--tip", "ends"]),
        # (accepted, exit 0: eld-tmd's rigid plate at the centroid of 'ends', outside the body
        # -- a rigid body's reference point need not lie in it; no sensor there)
        ("plate", "eld-tmd", ["--mesh", ell2, "--base", "inlet", "--tip", "ends"], 0),
    ]  # fmt: skip


def main() -> int:
    short = ["--T", "0.02", "--tau", "0.01", "--quiet", "--no-plots"]
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    handled = total = 0
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        for k, (item, command, argv, *status) in enumerate(cases(d)):
            if sys.argv[1:] and str(k) not in sys.argv[1:]:
                continue
            out = d / f"out{k}"
            argv = [str(a) for a in argv]
            run = [sys.executable, "-m", "rothe.cli.main", "run", command, *argv, *short]
            r = subprocess.run(run + ["--out", str(out)], env=env, capture_output=True, text=True)
            lines = r.stderr.strip().splitlines()
            shown = " ".join(Path(a).name if a.startswith(tmp) else a for a in argv)
            if status == [0]:
                ok = r.returncode == 0
            else:
                ok = r.returncode == 2 and len(lines) == 1 and not out.exists()
            handled, total = handled + ok, total + 1
            last = lines[-1] if lines else ""
            print(f"{k} | {item} | {command} {shown} | {r.returncode} | {len(lines)} | {last}")
    print(f"handled {handled} of {total}")
    return 0 if handled == total else 1


if __name__ == "__main__":
    sys.exit(main())
