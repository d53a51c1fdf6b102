"""A mosaic of measured reflectances: a built-in scene whose spectra are not of rank 3.

The ``natural`` scene lifts an sRGB photograph with a three-spectrum basis, so every pixel is
a mix of the same three spectra; the ColorChecker holds 24 flat patches.  A spectral prior is
flattered by both.  This scene lays out measured reflectances shipped with colour-science --
the GretagMacbeth/X-Rite ColorChecker (N. Ohta), the 30 patches of the PMC chart, the CIE 2024
test colour samples and the NIST CQS 9.0 samples, 84 spectra in all -- as a scene with the
structure of a real one:

* the frame is split into Voronoi cells around ``cells`` seed points;
* each cell blends two of the reflectances along a linear ramp in its own direction (so no
  cell is flat and neighbouring pixels hold different mixtures);
* a smooth shading field (a low-frequency sum of cosines, 0.35-1) multiplies everything, as
  illumination falloff and surface orientation do;
* the illuminant (D65 by default) multiplies the reflectance.

Its band Gram matrix has many more than three significant eigenvalues
(``tests/scenes/test_reflectances.py`` checks the singular values on 28 bands).  Everything derives from ``seed``: the same arguments
give the same cube.
"""

from __future__ import annotations

import numpy as np

from recon.errors import InputError
from scenes._common import check_shape, wavelengths_or_default
from scenes.spectra import illuminant as _illuminant
from scenes.spectra import sample_sd

__all__ = ["measured_reflectances", "reflectance_mosaic"]


def measured_reflectances(wavelengths) -> np.ndarray:
    """The 84 measured reflectances (float64, (84, L)) at ``wavelengths`` (within 400-700 nm):
    ColorChecker (N. Ohta), PMC, CIE 2024 test colour samples, NIST CQS 9.0."""
    import colour
    from colour.quality.datasets import SDS_TCS, SDS_VS

    sets = [colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"],
            colour.SDS_COLOURCHECKERS["PMC"], SDS_TCS["CIE 2024"], SDS_VS["NIST CQS 9.0"]]
    rows = []
    for sds in sets:
        for sd in sds.values():
            dom = np.asarray(sd.wavelengths, np.float64)
            rows.append(sample_sd(dom, np.asarray(sd.values, np.float64)[None], wavelengths,
                                  f"the reflectance {sd.name!r}")[0])
    return np.clip(np.stack(rows), 0.0, 1.0)


def reflectance_mosaic(shape=(256, 256), wavelengths=None, *, cells: int = 48, seed: int = 0,
                       illuminant: str = "D65") -> np.ndarray:
    """Radiance cube (H, W, L) float32: Voronoi cells, each a ramp between two measured
    reflectances, times a smooth shading, under ``illuminant`` (see the module notes)."""
    h, w = check_shape(shape)
    wl = wavelengths_or_default(wavelengths)
    if isinstance(cells, bool) or int(cells) != cells or not 1 <= int(cells) <= 4096:
        raise InputError(f"cells must be an integer in 1..4096, got {cells!r}")
    cells = int(cells)
    refl = measured_reflectances(wl)
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    yy, xx = (yy + 0.5) / h, (xx + 0.5) / w
    seeds = rng.random((cells, 2))
    # Nearest seed per pixel, one seed at a time (memory of two images, not cells of them).
    label = np.zeros((h, w), np.int64)
    best = np.full((h, w), np.inf)
    for i, (sy, sx) in enumerate(seeds):
        d = (yy - sy) ** 2 + (xx - sx) ** 2
        closer = d < best
        best[closer] = d[closer]
        label[closer] = i
    pair = rng.choice(refl.shape[0], size=(cells, 2), replace=True)
    angle = rng.uniform(0.0, 2.0 * np.pi, cells)
    # The ramp's coordinate: position along the cell's direction, scaled so that a cell of the
    # typical size (1/sqrt(cells) of the frame) spans most of it.
    span = 1.0 / np.sqrt(cells)
    t = ((yy - seeds[label, 0]) * np.sin(angle[label]) +
         (xx - seeds[label, 1]) * np.cos(angle[label])) / span + 0.5
    t = np.clip(t, 0.0, 1.0)
    shading = np.zeros((h, w))
    for _ in range(4):
        fy, fx = rng.uniform(0.5, 2.5, 2)
        py, px = rng.uniform(0.0, 2.0 * np.pi, 2)
        shading += np.cos(2 * np.pi * fy * yy + py) * np.cos(2 * np.pi * fx * xx + px)
    shading = 0.35 + 0.65 * (shading - shading.min()) / max(np.ptp(shading), 1e-12)
    light = _illuminant(illuminant, wl)
    ramp = (1.0 - t) * shading
    t *= shading
    # Band by band: memory of a few images and the float32 cube, whatever the grid.
    cube = np.empty((h, w, wl.size), np.float32)
    for k in range(wl.size):
        a, b = refl[pair[:, 0], k], refl[pair[:, 1], k]
        cube[:, :, k] = (ramp * a[label] + t * b[label]) * light[k]
    return cube
