"""Figures shared by both families: matplotlib set-up (:mod:`.common`), runs whose mesh
changes (:mod:`.adapt`) and sweeps (:mod:`.sweep`). Imported only where a figure is drawn.
"""
