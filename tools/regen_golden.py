"""Regenerate the image-regression goldens in ``tests/golden/`` on purpose.

Run this only after a change that is *meant* to alter the rendered frame or the reconstruction
(a design default, the optics, the sensor model, the calibration or the solver), then commit the
new files with that change::

    python3 tools/regen_golden.py            # writes tests/golden/{frame.npz,recon.npz,golden.json}
    python3 tools/regen_golden.py --check    # compare a fresh render with the goldens, write nothing

What the goldens are, how they are produced and the tolerances of the comparison are defined in
``tests/test_golden.py`` (this script imports it, so the test and the regeneration can never
disagree). The render and calibration use a fresh temporary cache folder, never the user's
cache, so the goldens do not depend on earlier runs. Files are written atomically.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def load_spec():
    """``tests/test_golden.py`` as a module (it is not part of an importable package)."""
    path = ROOT / "tests" / "test_golden.py"
    spec = importlib.util.spec_from_file_location("kaleidospec_test_golden", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=None,
                    help="folder to write (default tests/golden/)")
    ap.add_argument("--check", action="store_true",
                    help="only compare a fresh render and reconstruction with the goldens")
    a = ap.parse_args(argv)
    g = load_spec()
    out = a.out or g.GOLDEN_DIR
    with tempfile.TemporaryDirectory(prefix="kaleidospec-golden-") as cache:
        os.environ["KALEIDOSPEC_CACHE"] = cache
        t0 = time.perf_counter()
        if a.check:
            gold = g.load_goldens(out)
            p = g.produce()
            problems = g.compare_frames(p["frame"], gold["frame"])
            problems += g.compare_reconstructions(p["cube"], gold["cube"], p["truth_grid"],
                                                  gold["meta"]["psnr_truth_db"])
            for line in problems:
                print(f"differs: {line}")
            print(f"{'OK' if not problems else 'CHANGED'}: fresh images vs {out} "
                  f"({time.perf_counter() - t0:.1f} s)")
            return 1 if problems else 0
        paths = g.write_goldens(out)
    total = sum(p.stat().st_size for p in paths)
    for p in paths:
        print(f"wrote {p} ({p.stat().st_size / 1024:.1f} KiB)")
    print(f"{total / 1024:.1f} KiB in all, {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
