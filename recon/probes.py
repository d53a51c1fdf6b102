r"""Random probe cubes for the solvers' estimates (power iterations, Hutchinson probes).

A cube at the ``paper`` scale has 21 million voxels.  Drawn in one call, a standard normal
cube is first made in float64 and a Rademacher cube from an int64 index array: temporaries of
twice the float32 cube's size, each of whose pages the system has to supply afresh.  These draw the same values in slabs of :data:`SLAB` voxels written straight into
the float32 cube: NumPy's generators consume their bit stream value by value, so a
sequence of smaller draws continues it exactly as one large draw does (the tests compare
them to the bit).  A solve set up with these is the solve set up with the single draws.
"""

from __future__ import annotations

import numpy as np

__all__ = ["SLAB", "standard_normal", "rademacher"]

#: Voxels drawn at a time: the temporaries stay at a few MB.
SLAB = 1 << 18


def standard_normal(rng: np.random.Generator, shape, dtype=np.float32) -> np.ndarray:
    """``rng.standard_normal(shape).astype(dtype)``, without the float64 cube."""
    out = np.empty(shape, dtype=dtype)
    flat = out.reshape(-1)
    for a in range(0, flat.size, SLAB):
        b = min(flat.size, a + SLAB)
        flat[a:b] = rng.standard_normal(b - a)
    return out


def rademacher(rng: np.random.Generator, shape, dtype=np.float32,
               out: np.ndarray | None = None) -> np.ndarray:
    """``rng.choice(np.array([-1.0, 1.0], dtype), size=shape)`` (±1 with equal odds), without
    the int64 index cube; into ``out`` (of ``shape`` and ``dtype``) when given."""
    if out is None:
        out = np.empty(shape, dtype=dtype)
    elif (out.shape != tuple(shape) or out.dtype != np.dtype(dtype)
          or not out.flags.c_contiguous):
        raise ValueError(f"out must be C-contiguous, of shape {tuple(shape)} and dtype "
                         f"{np.dtype(dtype)}")
    flat = out.reshape(-1)
    for a in range(0, flat.size, SLAB):
        b = min(flat.size, a + SLAB)
        # choice() draws the index 0 or 1 as an int64 integer in [0, 2): -1 + 2 i.
        i = rng.integers(0, 2, size=b - a, dtype=np.int64)
        np.multiply(i, 2, out=flat[a:b], casting="unsafe")
        flat[a:b] -= 1
    return out
