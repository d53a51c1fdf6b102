"""Linear forward models of (multi-view) CASSI, each with an exact, dot-tested adjoint."""

from recon.operators.base import LinearOperator, MatrixOperator, dot_test

__all__ = ["LinearOperator", "MatrixOperator", "dot_test"]
