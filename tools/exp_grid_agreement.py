#!/usr/bin/env python3
"""Do a calibration's views agree on where its grid lies on the scene?

Every calibrated view puts each grid point somewhere on the scene (its homography, displacement
field and band offsets, followed through the simulator's exact optics:
:func:`kaleidospec.instrument.view_answers`).  A reconstruction from several views can only be
as sharp as those answers agree; the truth it is scored against sits at their mean
(:func:`kaleidospec.models.truth_on_grid`).  For every view this prints how far its answer lies
from the views' mean and from the centre view's, rms and largest over the grid (design-grid
pixels), and the rms over all views.  No scene is rendered: the calibration (cached by design
hash, rendered if missing) and the scene frames' transport are all it reads.

Usage::

    python3 tools/exp_grid_agreement.py                          # small, five views
    python3 tools/exp_grid_agreement.py --design paper --views 5
    python3 tools/exp_grid_agreement.py --views 9 --set band_step_nm=50
"""

from __future__ import annotations

import argparse
import sys

import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--design", default="small", help="design preset: small (default) or paper")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="FIELD=VALUE",
                    help="override a design field (repeatable)")
    ap.add_argument("--views", type=int, default=5, help="views calibrated (1..9, default 5)")
    a = ap.parse_args(argv)

    from kaleidospec.calibrate import calibrate
    from kaleidospec.instrument import design_for_views, get_design, parse_overrides, view_answers

    design = design_for_views(get_design(a.design, parse_overrides(a.overrides)), a.views)
    cal = calibrate(design, progress=True)
    _, answers = view_answers(design, cal)
    mean = [np.mean([ans[k] for ans in answers.values()], axis=0) for k in range(2)]
    centre = answers[0]
    print(f"design {a.design} ({design.hash}), {len(answers)} views, displacement fields: "
          f"{'measured' if cal.view_fields is not None else 'none'}")
    print(f"{'view':>5} {'from mean: rms':>15} {'max':>7} {'from centre: rms':>17} {'max':>7}  (px)")
    rms_all = []
    for view, (x, y) in answers.items():
        dm = np.hypot(x - mean[0], y - mean[1])
        dc = np.hypot(x - centre[0], y - centre[1])
        rms_all.append(float(np.sqrt(np.mean(dm ** 2))))
        print(f"{view:>5} {rms_all[-1]:15.3f} {dm.max():7.3f} {np.sqrt(np.mean(dc ** 2)):17.3f} "
              f"{dc.max():7.3f}")
    print(f"all views: {np.sqrt(np.mean(np.square(rms_all))):.3f} px rms from their mean")
    return 0


if __name__ == "__main__":
    sys.exit(main())
