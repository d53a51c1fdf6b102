"""Independent dense references for the operator tests: explicit matrices built with loops, to
compare the fast operators against."""

import math

import numpy as np


def shift_matrix(phi: float, w_in: int, w_out: int) -> np.ndarray:
    """Row-wise linear-interpolation shift: out[x] = (1-t) v[x-a] + t v[x-a-1] for the x in
    [0, w_out) (what lands outside is dropped)."""
    a = math.floor(phi)
    t = phi - a
    s = np.zeros((w_out, w_in))
    for u in range(w_in):
        for x, weight in ((u + a, 1.0 - t), (u + a + 1, t)):
            if 0 <= x < w_out and weight > 0:
                s[x, u] += weight
    return s


def flip_matrix(shape, axes) -> np.ndarray:
    """The permutation matrix of an image reversed along ``axes`` (0: rows, 1: columns)."""
    h, w = shape
    idx = np.arange(h * w).reshape(h, w)
    if 0 in axes:
        idx = idx[::-1]
    if 1 in axes:
        idx = idx[:, ::-1]
    return np.eye(h * w)[idx.ravel()]
