#!/usr/bin/env python3
"""Design sweep of the mirror length (same as ``kaleidospec sweep mirror-length``).

Every design point is rendered with the physical simulator and measured (view size,
minification, gaps, vignetting, dispersion span: predicted vs measured) and, unless
``--no-recon``, reconstructed (PSNR/SAM). Writes a CSV, a PNG and one JSON per point (reused
when the sweep is rerun or extended). Example::

    python tools/sweep_mirror_length.py --design small --start 150 --stop 420 --step 30 --views 5
"""

from __future__ import annotations

import sys

if __name__ == "__main__":
    from kaleidospec.cli import main

    main(["sweep", "mirror-length", *sys.argv[1:]])
