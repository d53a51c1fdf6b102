"""tools/exp_step.py: the converged top eigenvalue of the band metric's weighted Hessian."""

from __future__ import annotations

import numpy as np
import pytest
from tool_scripts import load_tool

from recon.operators.base import MatrixOperator

SHAPE = (3, 6, 5)


def test_converged_alpha_is_the_weighted_hessians_top_eigenvalue():
    """Against the dense eigenvalue of S^(-1/2) H^T H S^(-1/2), on an operator whose three
    bands differ in scale (so that a wrong weighting moves the answer)."""
    rng = np.random.default_rng(4)
    n = int(np.prod(SHAPE))
    h = rng.standard_normal((40, n)) * np.repeat([1.0, 0.3, 3.0], n // 3)[None, :]
    op = MatrixOperator(h.astype(np.float32), ishape=SHAPE, oshape=(40,))
    s = np.array([0.2, 1.0, 0.05])
    w = np.repeat(1.0 / np.sqrt(s), n // 3)
    top = np.linalg.eigvalsh((h * w).T @ (h * w))[-1]
    alpha, pairs = load_tool("exp_step").converged_alpha(op, s, 1e-8)
    assert alpha == pytest.approx(top, rel=1e-5)
    assert pairs >= 1
    # Unweighted, the top eigenvalue differs: the weights are applied.
    assert abs(np.linalg.eigvalsh(h.T @ h)[-1] - top) > 0.1 * top
