"""Spectral data for scenes: illuminants, measured reflectances, spectral upsampling.

All data come from colour-science and are resampled by linear interpolation onto the requested
band centres (nm). Scenes are *relative spectral radiance* = reflectance × illuminant, with the
illuminant scaled to a peak of 1 over 400–720 nm, so a perfect white reflector reads at most 1.
Cubes are shown as sRGB by :func:`recon.metrics.cube_to_srgb`.
"""

from __future__ import annotations

import numpy as np

from recon.errors import InputError

__all__ = [
    "ILLUMINANT_ALIASES",
    "check_wavelengths",
    "sample_sd",
    "illuminant",
    "colorchecker_reflectances",
    "colorchecker_names",
    "mallett2019_basis",
    "srgb_to_reflectance",
]

#: Short names → colour-science illuminant names. "LED" is CIE LED-B4 (phosphor white ≈ 5100 K).
ILLUMINANT_ALIASES = {"LED": "LED-B4", "D65": "D65", "A": "A", "E": "E", "D50": "D50"}


def check_wavelengths(wavelengths) -> np.ndarray:
    """Wavelengths as a float64 (L,) array; finite, positive and strictly increasing."""
    wl = np.atleast_1d(np.asarray(wavelengths, dtype=np.float64))
    if wl.ndim != 1 or wl.size == 0:
        raise InputError("wavelengths must be a non-empty 1-D list (nm)")
    if not np.all(np.isfinite(wl)) or np.any(wl <= 0) or np.any(np.diff(wl) <= 0):
        raise InputError("wavelengths must be finite, positive and strictly increasing (nm)")
    return wl


def sample_sd(domain: np.ndarray, values: np.ndarray, wavelengths, what: str) -> np.ndarray:
    """Linearly interpolate tabulated spectra ``values`` (..., N) on ``domain`` (N,) at
    ``wavelengths``; wavelengths outside the table raise :class:`InputError`."""
    wl = check_wavelengths(wavelengths)
    if wl[0] < domain[0] - 1e-9 or wl[-1] > domain[-1] + 1e-9:
        raise InputError(
            f"{what} is tabulated over {domain[0]:g}–{domain[-1]:g} nm; "
            f"wavelengths {wl[0]:g}–{wl[-1]:g} nm are not covered"
        )
    v = np.asarray(values, dtype=np.float64)
    idx = np.clip(np.searchsorted(domain, wl, side="right") - 1, 0, domain.size - 2)
    t = (wl - domain[idx]) / (domain[idx + 1] - domain[idx])
    return v[..., idx] * (1.0 - t) + v[..., idx + 1] * t


def illuminant(name: str, wavelengths) -> np.ndarray:
    """Relative spectral power of illuminant ``name`` (D65, A, LED, E, or any colour-science
    name), scaled to a peak of 1 over 400–720 nm, at ``wavelengths`` (float64)."""
    import colour

    key = ILLUMINANT_ALIASES.get(str(name), str(name))
    if key not in colour.SDS_ILLUMINANTS:
        raise InputError(f"unknown illuminant {name!r}; try D65, A, LED or E")
    sd = colour.SDS_ILLUMINANTS[key]
    dom, val = np.asarray(sd.wavelengths, np.float64), np.asarray(sd.values, np.float64)
    peak = sample_sd(dom, val, np.arange(400.0, 721.0, 1.0), f"illuminant {key}").max()
    return sample_sd(dom, val, wavelengths, f"illuminant {key}") / peak


def _colorchecker():
    import colour

    return colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]


def colorchecker_names() -> list[str]:
    """The 24 patch names in chart order (row-major from dark skin to black)."""
    return list(_colorchecker().keys())


def colorchecker_reflectances(wavelengths) -> np.ndarray:
    """Measured reflectances of the 24 ColorChecker patches (N. Ohta's data in colour-science),
    float64 (24, L), in chart order."""
    sds = list(_colorchecker().values())
    dom = np.asarray(sds[0].wavelengths, np.float64)
    vals = np.stack([np.asarray(s.values, np.float64) for s in sds])
    return sample_sd(dom, vals, wavelengths, "the ColorChecker data")


def mallett2019_basis(wavelengths) -> np.ndarray:
    """Mallett & Yuksel (2019) sRGB basis spectra, float64 (3, L): a linear sRGB triple
    (r, g, b) in [0, 1] lifts to the reflectance r·B_r + g·B_g + b·B_b, which stays in [0, 1]
    (the three sum to 1) and reproduces the colour under D65."""
    import colour

    b = colour.recovery.MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019
    return sample_sd(np.asarray(b.wavelengths, np.float64), np.asarray(b.values, np.float64).T,
                     wavelengths, "the Mallett-Yuksel basis")


def srgb_to_reflectance(rgb: np.ndarray, wavelengths) -> np.ndarray:
    """Lift an sRGB image (H, W, 3), encoded values in [0, 1], to reflectance (H, W, L) float32.

    The sRGB transfer function is undone first (IEC 61966-2-1), then the linear values are
    projected on the Mallett-Yuksel basis: one matrix product for the whole image.
    """
    v = np.clip(np.asarray(rgb, dtype=np.float32), 0.0, 1.0)
    lin = np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4).astype(np.float32)
    basis = mallett2019_basis(wavelengths).astype(np.float32)
    return np.clip(lin @ basis, 0.0, 1.0).astype(np.float32)
