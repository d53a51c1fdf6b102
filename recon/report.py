"""Figures of a reconstruction against its reference (matplotlib, Agg backend, atomic writes).

- :func:`band_montage`: every band of the truth and of each reconstruction, one row each, on a
  common grey scale;
- :func:`spectra_plot`: mean spectra of a few regions, reconstruction(s) against the truth.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["band_montage", "spectra_plot"]


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path) -> Path:
    from recon.io.atomic import atomic_path

    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=path.suffix.lstrip(".") or "png", dpi=100)
    return path


def band_montage(path, truth, cubes: dict, wavelengths, max_bands: int = 12) -> Path:
    """A grid of band images: the truth in the first row, then one row per reconstruction.

    Parameters
    ----------
    path : path (``.png``)
    truth : (H, W, L) array
    cubes : dict label -> (H, W, L) array
        Reconstructions (e.g. keyed by view count).
    wavelengths : (L,) array
    max_bands : int
        At most this many bands (evenly spread) are shown.
    """
    plt = _pyplot()
    t = np.asarray(truth, dtype=np.float32)
    wl = np.asarray(wavelengths, dtype=np.float64)
    n_bands = t.shape[2]
    show = np.unique(np.round(np.linspace(0, n_bands - 1, min(max_bands, n_bands))).astype(int))
    rows = [("truth", t)] + [(f"{k} views" if isinstance(k, int) else str(k), np.asarray(c))
                             for k, c in cubes.items()]
    vmax = float(np.percentile(t, 99.5)) or 1.0
    fig, axes = plt.subplots(len(rows), show.size, figsize=(1.3 * show.size, 1.4 * len(rows)),
                             squeeze=False)
    for r, (label, c) in enumerate(rows):
        for j, l in enumerate(show):
            ax = axes[r, j]
            ax.imshow(c[:, :, l], cmap="gray", vmin=0.0, vmax=vmax, interpolation="nearest")
            ax.set_xticks([]), ax.set_yticks([])
            if r == 0:
                ax.set_title(f"{wl[l]:.0f} nm", fontsize=8)
            if j == 0:
                ax.set_ylabel(label, fontsize=8)
    fig.tight_layout(pad=0.3)
    try:
        return _save(fig, path)
    finally:
        plt.close(fig)


def spectra_plot(path, truth, cubes: dict, wavelengths, regions) -> Path:
    """Mean spectrum of each region: truth (black) against each reconstruction.

    Parameters
    ----------
    regions : sequence of (label, (y0, x0, h, w))
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
        return _save(fig, path)
    finally:
        plt.close(fig)
