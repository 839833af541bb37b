"""Files, and nothing of either family: trajectories (:mod:`.trajectory`), checkpoints and
resume (:mod:`.checkpoint`; a problem supplies its own ``fingerprint()``), atomic writes
(:mod:`.atomic`), outputs committed together (:mod:`.outputs`), XDMF (:mod:`.xdmf`) and VTU
series of changing meshes (:mod:`.mesh_series`).
"""
