"""Optical glass: Sellmeier refractive index and the dispersion of a prism.

The index of every glass follows the three-term Sellmeier equation with Schott's (or Malitson's)
published coefficients, λ in µm:

.. math:: n^2(\\lambda) = 1 + \\sum_{i=1}^{3} \\frac{B_i \\lambda^2}{\\lambda^2 - C_i}

A prism of apex angle :math:`A` set at minimum deviation for a centre wavelength :math:`\\lambda_c`
receives the collimated beam at the fixed incidence angle

.. math:: \\theta_1 = \\arcsin\\big(n(\\lambda_c) \\sin(A/2)\\big).

Every other wavelength keeps that incidence angle and leaves at

.. math:: \\theta_2 = \\arcsin\\!\\big(\\sin\\theta_1 / n\\big), \\quad
          \\theta_4 = \\arcsin\\!\\big(n \\sin(A - \\theta_2)\\big), \\quad
          \\delta(\\lambda) = \\theta_1 + \\theta_4 - A .

An imaging lens of focal length :math:`f` whose axis follows the centre wavelength's exit ray puts
wavelength λ at :math:`x(\\lambda) = f \\tan(\\delta(\\lambda_c) - \\delta(\\lambda))` from the
centre band's image. With the sign chosen here, longer wavelengths (deviated less) land at larger
sensor columns, as in the standard CASSI convention (band *l* shifted right by step·*l*).

Total internal reflection at the exit face (:math:`n \\sin(A - \\theta_2) > 1`) and apex angles
for which minimum deviation cannot exist (:math:`n \\sin(A/2) \\ge 1`) raise
:class:`recon.errors.InputError`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from recon.errors import InputError

__all__ = [
    "GLASSES",
    "Sellmeier",
    "get_glass",
    "refractive_index",
    "min_deviation_incidence_rad",
    "deviation_rad",
    "tir_free",
    "dispersion_offsets_mm",
    "dispersion_px",
    "apex_for_span",
]


@dataclass(frozen=True)
class Sellmeier:
    """Three-term Sellmeier coefficients: ``B`` (dimensionless) and ``C`` (µm²)."""

    name: str
    B: tuple[float, float, float]
    C: tuple[float, float, float]
    source: str

    def n(self, wavelength_nm: np.ndarray | float) -> np.ndarray:
        """Refractive index at ``wavelength_nm`` (nm), as float64."""
        lam2 = (np.asarray(wavelength_nm, dtype=np.float64) * 1e-3) ** 2
        n2 = 1.0 + sum(b * lam2 / (lam2 - c) for b, c in zip(self.B, self.C))
        return np.sqrt(n2)


#: Glasses by name. Schott coefficients from the Schott optical glass data sheets; fused silica
#: from Malitson (1965).
GLASSES: dict[str, Sellmeier] = {
    "BK7": Sellmeier(
        "N-BK7",
        (1.03961212, 0.231792344, 1.01046945),
        (0.00600069867, 0.0200179144, 103.560653),
        "Schott data sheet N-BK7 (n_d = 1.5168)",
    ),
    "F2": Sellmeier(
        "F2",
        (1.34533359, 0.209073176, 0.937357162),
        (0.00997743871, 0.0470450767, 111.886764),
        "Schott data sheet F2 (n_d = 1.6200)",
    ),
    "SF10": Sellmeier(
        "N-SF10",
        (1.62153902, 0.256287842, 1.64447552),
        (0.0122241457, 0.0595736775, 147.468793),
        "Schott data sheet N-SF10 (n_d = 1.7283)",
    ),
    "SF11": Sellmeier(
        "N-SF11",
        (1.73759695, 0.313747346, 1.89878101),
        (0.013188707, 0.0623068142, 155.23629),
        "Schott data sheet N-SF11 (n_d = 1.7847)",
    ),
    "FusedSilica": Sellmeier(
        "Fused silica",
        (0.6961663, 0.4079426, 0.8974794),
        (0.0684043**2, 0.1162414**2, 9.896161**2),
        "Malitson 1965 (n_d = 1.4585)",
    ),
}
_ALIASES = {"N-BK7": "BK7", "N-SF10": "SF10", "N-SF11": "SF11", "SILICA": "FusedSilica",
            "FUSEDSILICA": "FusedSilica", "FUSED_SILICA": "FusedSilica"}


def get_glass(name: str) -> Sellmeier:
    """The glass called ``name`` (case-insensitive; ``N-`` prefixes accepted)."""
    key = str(name).strip()
    for cand in (key, key.upper(), _ALIASES.get(key.upper(), "")):
        if cand in GLASSES:
            return GLASSES[cand]
    for k in GLASSES:
        if k.upper() == key.upper():
            return GLASSES[k]
    raise InputError(f"unknown glass {name!r}; known: {', '.join(GLASSES)}")


def refractive_index(glass: str, wavelength_nm: np.ndarray | float) -> np.ndarray:
    """Sellmeier index :math:`n(\\lambda)` of ``glass`` at ``wavelength_nm`` (nm)."""
    wl = np.asarray(wavelength_nm, dtype=np.float64)
    if not np.all(np.isfinite(wl)) or np.any(wl <= 0):
        raise InputError("wavelengths must be finite and positive (nm)")
    return get_glass(glass).n(wl)


def min_deviation_incidence_rad(glass: str, apex_deg: float, center_nm: float) -> float:
    """Incidence angle θ₁ (rad) that puts the prism at minimum deviation for ``center_nm``.

    θ₁ = arcsin(n(λ_c)·sin(A/2)); raises :class:`InputError` when no such angle exists.
    """
    a = float(apex_deg)
    if not np.isfinite(a) or a <= 0.0 or a >= 180.0:
        raise InputError(f"prism apex angle must lie in (0, 180) degrees, got {apex_deg}")
    n_c = float(refractive_index(glass, center_nm))
    s = n_c * np.sin(np.radians(a) / 2.0)
    if s >= 1.0:
        crit = 2.0 * np.degrees(np.arcsin(1.0 / n_c))
        raise InputError(
            f"prism apex {a:g}° in {glass} cannot reach minimum deviation at {center_nm:g} nm "
            f"(total internal reflection; apex must be < {crit:.2f}°)"
        )
    return float(np.arcsin(s))


def _exit_sine(glass: str, apex_deg: float, center_nm: float, wavelength_nm) -> np.ndarray:
    """sin θ₄ = n·sin(A − θ₂) at the exit face; > 1 means total internal reflection."""
    theta1 = min_deviation_incidence_rad(glass, apex_deg, center_nm)
    n = refractive_index(glass, wavelength_nm)
    theta2 = np.arcsin(np.sin(theta1) / n)
    return n * np.sin(np.radians(apex_deg) - theta2)


def tir_free(glass: str, apex_deg: float, center_nm: float, wavelength_nm) -> np.ndarray:
    """Boolean flags: True where ``wavelength_nm`` leaves the prism without total internal
    reflection (incidence fixed by minimum deviation at ``center_nm``).

    An impossible apex (no minimum-deviation incidence) raises :class:`InputError`.
    """
    return np.abs(_exit_sine(glass, apex_deg, center_nm, wavelength_nm)) < 1.0


def deviation_rad(glass: str, apex_deg: float, center_nm: float, wavelength_nm) -> np.ndarray:
    """Deviation δ(λ) = θ₁ + θ₄ − A (rad) at a fixed incidence (minimum deviation at ``center_nm``).

    Raises :class:`InputError` when any wavelength is totally internally reflected.
    """
    s4 = _exit_sine(glass, apex_deg, center_nm, wavelength_nm)
    if np.any(np.abs(s4) >= 1.0):
        bad = np.atleast_1d(np.asarray(wavelength_nm, dtype=np.float64))[
            np.atleast_1d(np.abs(s4) >= 1.0)
        ]
        raise InputError(
            f"total internal reflection in the {glass} prism (apex {apex_deg:g}°) at "
            f"{bad.min():g} nm: the light does not leave the exit face"
        )
    theta1 = min_deviation_incidence_rad(glass, apex_deg, center_nm)
    return theta1 + np.arcsin(s4) - np.radians(apex_deg)


def dispersion_offsets_mm(
    glass: str, apex_deg: float, center_nm: float, focal_mm: float, wavelength_nm
) -> np.ndarray:
    """Image offset x(λ) = f·tan(δ(λ_c) − δ(λ)) in mm on the sensor, relative to ``center_nm``.

    Positive for wavelengths longer than the centre one (they are deviated less).
    """
    if not np.isfinite(focal_mm) or focal_mm <= 0:
        raise InputError(f"imaging focal length must be positive, got {focal_mm}")
    d_c = deviation_rad(glass, apex_deg, center_nm, center_nm)
    d = deviation_rad(glass, apex_deg, center_nm, wavelength_nm)
    return float(focal_mm) * np.tan(d_c - d)


def dispersion_px(design, wavelength_nm=None) -> np.ndarray:
    """Horizontal shift φ(λ) in sensor pixels of each band relative to the centre band.

    Parameters
    ----------
    design : sim.optics.design.Design
        Uses ``prism_glass``, ``prism_apex_deg``, ``prism_center_nm``, ``imaging_focal_mm`` and
        ``sensor_pixel_um``.
    wavelength_nm : array_like, optional
        Wavelengths (nm); the design's band centres by default.

    Returns
    -------
    numpy.ndarray
        φ(λ) = f_img·tan(δ(λ_c) − δ(λ)) / pixel, float64, increasing with λ.
    """
    wl = design.wavelengths if wavelength_nm is None else np.asarray(wavelength_nm, np.float64)
    x = dispersion_offsets_mm(
        design.prism_glass, design.prism_apex_deg, design.prism_center_nm,
        design.imaging_focal_mm, wl,
    )
    return x / (design.sensor_pixel_um * 1e-3)


def apex_for_span(
    glass: str,
    span_px: float,
    lo_nm: float,
    hi_nm: float,
    center_nm: float,
    focal_mm: float,
    pixel_um: float,
) -> float:
    """The apex angle (degrees) at which the dispersion from ``lo_nm`` to ``hi_nm`` spans
    ``span_px`` pixels, found by bisection (the span grows monotonically with the apex).

    Raises :class:`InputError` when the span cannot be reached before total internal reflection.
    """
    wl = np.array([lo_nm, hi_nm], dtype=np.float64)

    def span(a: float) -> float:
        x = dispersion_offsets_mm(glass, a, center_nm, focal_mm, wl)
        return float(x[1] - x[0]) / (pixel_um * 1e-3)

    lo = 1e-3
    # The largest usable apex: both ends of the band still leave the prism.
    hi = 2.0 * np.degrees(np.arcsin(1.0 / float(refractive_index(glass, center_nm)))) - 1e-6
    for _ in range(200):
        try:
            if np.all(tir_free(glass, hi, center_nm, wl)):
                break
        except InputError:
            pass
        hi -= 0.05
    if span(hi) < span_px:
        raise InputError(
            f"{glass} cannot disperse {lo_nm:g}–{hi_nm:g} nm over {span_px:g} px with a "
            f"{focal_mm:g} mm lens before total internal reflection (max {span(hi):.1f} px)"
        )
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if span(mid) < span_px:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)
