r"""The contract between priors and solvers.

A prior is a regulariser :math:`\varphi` (its weight included) known through its proximal map

.. math::

    \mathrm{prox}_{s\varphi}(v) = \arg\min_x \tfrac12\|x - v\|_2^2 + s\,\varphi(x),

or, for a plug-and-play prior, through a denoiser used in its place (the step :math:`s` then
sets the denoising strength).  Solvers see only this contract, so any prior works with any
solver that can take it (proximal gradient / FISTA, GAP, ADMM / half-quadratic splitting).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

__all__ = ["Prior"]


@runtime_checkable
class Prior(Protocol):
    """A regulariser on band-major ``(L, H, W)`` cubes.

    Methods
    -------
    prox(v, step, out=None)
        :math:`\\mathrm{prox}_{s\\varphi}(v)` with :math:`s` = ``step`` > 0, into ``out`` when
        given (``out`` may be ``v``).  May keep warm-start state between calls.
    value(x)
        :math:`\\varphi(x)`, or ``None`` where the prior defines no value (a denoiser).
    reset()
        Forget any warm-start state (a new problem begins).
    """

    def prox(self, v: np.ndarray, step: float, out: np.ndarray | None = None) -> np.ndarray: ...

    def value(self, x: np.ndarray) -> float | None: ...

    def reset(self) -> None: ...
