r"""Starting points of the iterative solvers.

The usual start of a proximal-gradient solver is the back-projection
:math:`x_0 = H^\top g / L`.  On a coded-aperture imager it carries the mask's pattern: every
voxel is weighted by the mask pixels its rays cross, and the prior (TV) must then smooth that
pattern away, one small step per iteration.  The normalised back-projection

.. math::

    x_0 = \frac{H^\top g}{H^\top H\,\mathbf 1} \qquad\text{(element-wise, where }
    H^\top H\mathbf 1 > \epsilon \max H^\top H\mathbf 1\text{, else 0)}

divides the weighting out: for a constant cube :math:`x = c\,\mathbf 1` it returns :math:`c`
exactly, and in general a local, mask-weighted average of the scene, without the pattern.
It costs one forward and two adjoints.  It changes only the start: the objective, and so
the minimiser, are the solver's.
"""

from __future__ import annotations

import numpy as np

from recon.errors import InputError
from recon.operators.base import LinearOperator

__all__ = ["STARTS", "normalised_backprojection"]

#: The starts a solver's ``start=`` takes: ``"adjoint"`` (:math:`H^\top g` over the step's
#: Lipschitz constant, the solvers' own) and ``"normalised"`` (:func:`normalised_backprojection`).
STARTS = ("adjoint", "normalised")
#: :math:`\epsilon`: voxels whose response :math:`H^\top H\mathbf 1` is below this fraction of the
#: largest are barely seen; they start at 0.
FLOOR = 1e-3


def normalised_backprojection(op: LinearOperator, g: np.ndarray, dtype=np.float32,
                              htg: np.ndarray | None = None) -> np.ndarray:
    r""":math:`H^\top g / H^\top H\mathbf 1` (see the module notes), in ``dtype``.

    Parameters
    ----------
    op : LinearOperator
    g : ndarray, shape ``op.oshape``
    dtype
        The solver's precision.
    htg : ndarray, optional
        :math:`H^\top g` when the caller has it.

    Raises
    ------
    InputError
        The operator's response to a constant cube is nowhere positive.
    """
    den = np.asarray(op.adjoint(op.forward(np.ones(op.ishape, dtype=dtype))), dtype=dtype)
    top = float(den.max())
    if not top > 0:
        raise InputError("the operator's response to a constant cube is nowhere positive: "
                         "no normalised back-projection (use the adjoint start)")
    num = np.asarray(op.adjoint(g) if htg is None else htg, dtype=dtype)
    seen = den > FLOOR * top
    out = np.zeros(op.ishape, dtype=dtype)
    np.divide(num, den, out=out, where=seen)
    return out
