#!/usr/bin/env python3
"""Design sweep of the prism apex (same as ``kaleidospec sweep prism-apex``).

Every design point is rendered with the physical simulator and measured (view size,
minification, gaps, vignetting, dispersion span: predicted vs measured) and, unless
``--no-recon``, reconstructed (PSNR/SAM). Writes a CSV, a PNG and one JSON per point (reused
when the sweep is rerun or extended). Example::

    python tools/sweep_prism_apex.py --design small --start 25 --stop 70 --step 5 --views 5
"""

from __future__ import annotations

import sys

if __name__ == "__main__":
    from kaleidospec.cli import main

    main(["sweep", "prism-apex", *sys.argv[1:]])
