r"""A forward model held as one sparse matrix: :math:`g = A f` on flattened arrays.

The most general linear instrument: row :math:`i` of :math:`A` lists which cube entries a
measurement pixel sees and with what weight.  Two system matrices take this form: the
simulator's exact transport (:mod:`sim.transport.oracle`) and the footprints measured with comb targets
(:mod:`recon.calibration.footprint`).  Columns follow the cube's band-major layout
``(L, H, W)``, rows the measurement's ``(K, Hv, Wm)``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from recon.errors import InputError
from recon.operators.base import LinearOperator


class SparseMatrixOperator(LinearOperator):
    r"""``x -> A x`` with a sparse :math:`A`, its exact adjoint :math:`A^\top` and row norms.

    Parameters
    ----------
    matrix : scipy.sparse matrix, (prod(oshape), prod(ishape))
        Kept as float32 CSR; its transpose is built once (twice the matrix's memory, for a
        row-parallel adjoint).
    ishape, oshape : tuple of int
    """

    def __init__(self, matrix, ishape, oshape):
        if not sp.issparse(matrix):
            raise InputError(f"expected a scipy.sparse matrix, got {type(matrix).__name__}")
        super().__init__(ishape, oshape)
        want = (int(np.prod(self.oshape)), int(np.prod(self.ishape)))
        if matrix.shape != want:
            raise InputError(f"matrix is {matrix.shape[0]}x{matrix.shape[1]}, but {self.ishape}"
                             f" -> {self.oshape} needs {want[0]}x{want[1]}")
        self.matrix = sp.csr_matrix(matrix, dtype=np.float32)
        if not np.all(np.isfinite(self.matrix.data)):
            raise InputError("matrix holds non-finite values")
        self._t = self.matrix.T.tocsr()
        self._rn = None

    @staticmethod
    def _dtype(a):
        return np.float64 if a.dtype == np.float64 else np.float32

    def _forward(self, x):
        dt = self._dtype(x)
        return (self.matrix @ np.ascontiguousarray(x, dtype=dt).ravel()).astype(
            dt, copy=False).reshape(self.oshape)

    def _adjoint(self, y):
        dt = self._dtype(y)
        return (self._t @ np.ascontiguousarray(y, dtype=dt).ravel()).astype(
            dt, copy=False).reshape(self.ishape)

    def row_norms_sq(self):
        if self._rn is None:
            m = self.matrix.astype(np.float64)
            self._rn = np.asarray(m.multiply(m).sum(axis=1)).reshape(self.oshape)
        return self._rn.copy()

    def __repr__(self):
        return f"<{type(self).__name__} {self.ishape} -> {self.oshape}, {self.matrix.nnz} entries>"
