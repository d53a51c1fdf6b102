"""Linear forward models of (multi-view) CASSI, each with an exact, dot-tested adjoint.

Working layout is band-major: cubes are (L, H, W), measurements (K, Hv, Wm), float32.
"""

from recon.operators.bandwarp import BandWarpCassi
from recon.operators.base import LinearOperator, MatrixOperator, ScaledOperator, dot_test
from recon.operators.blur import BlurredOperator
from recon.operators.calibrated import CalibratedCassi
from recon.operators.cassi import CassiOperator, View, kaleidoscope_cassi, standard_cassi
from recon.operators.dispersion import Dispersion
from recon.operators.mask import MaskModulation
from recon.operators.smeared import SmearedCassi, taps_from_positions
from recon.operators.sparse import SparseMatrixOperator
from recon.operators.warp import (DisplacementField, Flip, HomographyWarp, Identity, Translate,
                                  Warp, WarpOperator)

__all__ = [
    "LinearOperator", "MatrixOperator", "ScaledOperator", "dot_test",
    "View", "CassiOperator", "standard_cassi", "kaleidoscope_cassi", "CalibratedCassi",
    "BandWarpCassi",
    "SmearedCassi", "taps_from_positions", "SparseMatrixOperator", "BlurredOperator",
    "Dispersion", "MaskModulation",
    "Warp", "Identity", "Flip", "Translate", "HomographyWarp", "DisplacementField", "WarpOperator",
]
