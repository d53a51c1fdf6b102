"""Pictures of a reconstruction, alone or against its reference (atomic writes).

- :func:`srgb_image` and :func:`write_png`: the display sRGB rendering of a cube (CIE 1931 2°,
  flat-white balance, γ 2.2) and its 8-bit PNG;
- :func:`band_montage`: every band of the truth (when there is one) and of each reconstruction,
  one row each, on a common grey scale (matplotlib, Agg backend);
- :func:`spectra_plot`: mean spectra of a few regions, reconstruction(s) against the truth;
  :func:`grid_regions` picks such regions when the scene suggests none.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["srgb_image", "write_png", "band_montage", "spectra_plot", "grid_regions"]

#: A cube shown alone (:func:`band_montage`): at most this many bands, this many a line.
SHEET_BANDS = 28
SHEET_COLUMNS = 7


def srgb_image(cube, wavelengths, peak: float | None = None) -> tuple[np.ndarray, float]:
    """The display sRGB rendering of a cube and the exposure it used.

    Parameters
    ----------
    cube : (H, W, L) array
    wavelengths : (L,) array
        In nm.
    peak : float, optional
        Luminance shown as white.  Default: the 99th percentile of the cube's luminance Y (a
        few hot pixels do not darken the picture); pass one picture's ``peak`` on to the next
        so that they compare (a reconstruction exposed like its truth).

    Returns
    -------
    rgb : (H, W, 3) float32 array in [0, 1]
    peak : float
    """
    import math

    from recon.metrics import cube_to_srgb, cube_to_xyz

    if peak is None:
        peak = float(np.percentile(cube_to_xyz(cube, wavelengths)[..., 1], 99.0))
        if not (math.isfinite(peak) and peak > 0):
            peak = 1.0  # a black cube: any exposure shows it black
    return cube_to_srgb(cube, wavelengths, peak=peak), peak


def write_png(path, rgb, *, protect=()) -> Path:
    """Write an (H, W, 3) image with values in [0, 1] as an 8-bit PNG, atomically."""
    import imageio.v3 as iio

    from recon.io.atomic import atomic_path

    path = Path(path)
    with atomic_path(path, protect=protect) as tmp:
        iio.imwrite(tmp, np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8), extension=".png")
    return path


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path, protect=()) -> Path:
    from recon.io.atomic import atomic_path

    path = Path(path)
    with atomic_path(path, protect=protect) as tmp:
        fig.savefig(tmp, format=path.suffix.lstrip(".") or "png", dpi=100)
    return path


def band_montage(path, truth, cubes: dict, wavelengths, max_bands: int = 12, *,
                 protect=()) -> Path:
    """A grid of band images on a common grey scale: the truth in the first row, then one row
    per reconstruction; a cube alone is laid out as a sheet of its bands instead.

    Parameters
    ----------
    path : path (``.png``)
    truth : (H, W, L) array or None
        The reference; None leaves its row out (the grey scale then comes from the first
        reconstruction).
    cubes : dict label -> (H, W, L) array
        Reconstructions (e.g. keyed by view count).
    wavelengths : (L,) array
    max_bands : int
        At most this many bands (evenly spread) are shown per row.  A cube alone (no truth,
        one reconstruction) shows up to :data:`SHEET_BANDS` bands, :data:`SHEET_COLUMNS` a
        line: every band of a 28-band capture.
    protect : iterable of path-like
        Inputs that ``path`` must not overwrite.
    """
    plt = _pyplot()
    rows = [(f"{k} views" if isinstance(k, int) else str(k), np.asarray(c))
            for k, c in cubes.items()]
    if truth is not None:
        rows.insert(0, ("truth", np.asarray(truth, dtype=np.float32)))
    t = rows[0][1]
    wl = np.asarray(wavelengths, dtype=np.float64)
    n_bands = t.shape[2]
    sheet = len(rows) == 1
    n_show = min(SHEET_BANDS if sheet else max_bands, n_bands)
    show = np.unique(np.round(np.linspace(0, n_bands - 1, n_show)).astype(int))
    vmax = float(np.percentile(t, 99.5)) or 1.0
    if sheet:
        cols = min(SHEET_COLUMNS, show.size)
        lines = -(-show.size // cols)
        cells = [(show[i], i // cols, i % cols) for i in range(show.size)]
        fig, axes = plt.subplots(lines, cols, figsize=(1.6 * cols, 1.75 * lines), squeeze=False)
        for ax in axes.flat[show.size:]:
            ax.axis("off")
    else:
        cells = [(l, r, j) for r in range(len(rows)) for j, l in enumerate(show)]
        fig, axes = plt.subplots(len(rows), show.size, figsize=(1.3 * show.size, 1.4 * len(rows)),
                                 squeeze=False)
    for l, r, j in cells:
        label, c = rows[0 if sheet else r]
        ax = axes[r, j]
        ax.imshow(c[:, :, l], cmap="gray", vmin=0.0, vmax=vmax, interpolation="nearest")
        ax.set_xticks([]), ax.set_yticks([])
        if sheet or r == 0:
            ax.set_title(f"{wl[l]:.0f} nm", fontsize=8)
        if j == 0 and not sheet:
            ax.set_ylabel(label, fontsize=8)
    fig.tight_layout(pad=0.3)
    try:
        return _save(fig, path, protect)
    finally:
        plt.close(fig)


def spectra_plot(path, truth, cubes: dict, wavelengths, regions, *, protect=()) -> Path:
    """Mean spectrum of each region: truth (black) against each reconstruction.

    Parameters
    ----------
    regions : sequence of (label, (y0, x0, h, w))
    protect : iterable of path-like
        Inputs that ``path`` must not overwrite.
    """
    plt = _pyplot()
    wl = np.asarray(wavelengths, dtype=np.float64)
    regions = list(regions)
    n = max(1, len(regions))
    cols = min(3, n)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.4 * rows), squeeze=False)
    for i, (label, (y0, x0, h, w)) in enumerate(regions):
        ax = axes[i // cols, i % cols]
        sl = (slice(y0, y0 + h), slice(x0, x0 + w))
        ax.plot(wl, np.asarray(truth)[sl].mean(axis=(0, 1)), "k-", lw=2, label="truth")
        for k, c in cubes.items():
            ax.plot(wl, np.asarray(c)[sl].mean(axis=(0, 1)), lw=1,
                    label=f"{k} views" if isinstance(k, int) else str(k))
        ax.set_title(label, fontsize=8)
        ax.set_xlabel("nm", fontsize=7)
        ax.tick_params(labelsize=7)
    for j in range(len(regions), rows * cols):
        axes[j // cols, j % cols].axis("off")
    axes[0, 0].legend(fontsize=6)
    fig.tight_layout(pad=0.3)
    try:
        return _save(fig, path, protect)
    finally:
        plt.close(fig)


def grid_regions(shape) -> list[tuple[str, tuple[int, int, int, int]]]:
    """Four small squares, one in each quadrant of an image of ``shape`` (H, W, ...), for
    :func:`spectra_plot` when nothing better is known about the scene.

    Returns
    -------
    list of (label, (y0, x0, h, w))
        The label is the square's top-left corner, ``"(y, x)"``.
    """
    h, w = int(shape[0]), int(shape[1])
    s = min(max(2, min(h, w) // 12), max(1, min(h, w) // 4))  # inside its quadrant
    return [(f"({y}, {x})", (y, x, s, s)) for y, x in
            ((h // 4, w // 4), (h // 4, max(0, 3 * w // 4 - s)),
             (max(0, 3 * h // 4 - s), w // 4), (max(0, 3 * h // 4 - s), max(0, 3 * w // 4 - s)))]
