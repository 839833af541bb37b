"""Frozen arrays: read-only arrays that own their data, written once by a checkpoint.

Its own module because both :mod:`rothe.io.checkpoint` (which writes them once) and
:mod:`rothe.io.mesh_series` (which freezes the meshes it stores) need it, and the checkpoint
already imports the trajectory, which reads mesh series.
"""

from __future__ import annotations

import numpy as np


def frozen(array) -> np.ndarray:
    """A read-only array that owns its data, with the values of ``array`` (not copied when it
    already is one).

    The checkpoint writes a frozen array once (into ``arrays-<seq>.npz``) and only refers to it
    in later checkpoints, as long as the state holds that same object: the contract is that a
    frozen array never changes. A stepper whose state grows with the run (the meshes of a mesh
    series, the kept fields of an adaptive run) freezes what it appends and returns the same
    objects from every ``checkpoint_state``, so that checkpointing costs O(K) in total.
    """
    if isinstance(array, np.ndarray) and is_frozen(array):
        return array
    out = np.array(array, copy=True)
    out.setflags(write=False)
    return out


def is_frozen(array) -> bool:
    """Whether ``array`` is read-only and owns its data (see :func:`frozen`)."""
    return isinstance(array, np.ndarray) and not array.flags.writeable and array.flags.owndata
