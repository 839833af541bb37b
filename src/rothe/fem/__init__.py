"""The shared finite element layer, which knows neither family: meshes (:mod:`.mesh`), scalar
P1 (:mod:`.scalar`) and vector P1/P2 spaces (:mod:`.elasticity`), evaluation of fields on
cells and facets for error indicators (:mod:`.simplex`), linear solvers (:mod:`.linear`) and mesh
adaptation (:mod:`.adapt`).
"""
