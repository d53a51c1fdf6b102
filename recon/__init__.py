"""kaleidospec.recon: reconstruction of hyperspectral cubes from (multi-view) CASSI frames.

This package sees only raw frames and calibration captures, as it would with real hardware: it
never imports :mod:`sim` or Mitsuba.  Sub-packages follow sigpy's split:

- :mod:`recon.operators`: linear forward models with exact adjoints,
- :mod:`recon.prox`: proximal maps (total variation),
- :mod:`recon.solvers`: iterative algorithms (TwIST, GAP-TV, ...),
- :mod:`recon.metrics`, :mod:`recon.io`: evaluation and file formats.
"""

from recon.errors import InputError

__all__ = ["InputError"]
