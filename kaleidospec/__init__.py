"""kaleidospec: simulate and reconstruct a kaleidoscopic multisampling CASSI.

The command line lives in :mod:`kaleidospec.cli`; the work is done by :mod:`sim` (Mitsuba 3
simulator), :mod:`scenes` (built-in hyperspectral targets) and :mod:`recon` (reconstruction).
"""

__version__ = "0.1.0"
