"""Efficiency of the RIS residual indicator on a manufactured step problem (rothe.ris.efficiency):
eta / |||e||| in a band on uniform and adapted meshes (the tables on finer meshes:
benchmarks/adapt_efficiency.py)."""

from __future__ import annotations

import numpy as np
import pytest

from rothe.ris.efficiency import ris_study

# measured (benchmarks/adapt_efficiency.py): 1.5-7 on these coarse meshes
RIS_BAND = (1.3, 8.0)


@pytest.mark.parametrize("dim, max_dofs", [(2, 1500), (3, 250)])
def test_ris_efficiency_band(dim, max_dofs):
    for adaptive in (False, True):
        rows = ris_study(
            dim, "front", adaptive=adaptive, max_dofs=max_dofs, n0=4 if dim == 2 else 2
        )
        eff = np.array([r["efficiency"] for r in rows])
        assert all(r["positive"] for r in rows)
        assert RIS_BAND[0] <= eff.min() and eff.max() <= RIS_BAND[1], eff
