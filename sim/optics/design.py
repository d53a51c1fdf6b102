"""The instrument's design: every physical parameter of the kaleidoscopic CASSI in one record.

:class:`Design` is a frozen dataclass whose defaults are the paper's values (Jeon, Choi and Kim,
"Multisampling compressive video spectroscopy", Sec. 4; see docs/design.md). Everything else in
``sim`` (the Mitsuba optics, the transport cache, the sensor) reads its parameters from a
``Design``, and every raw frame carries :attr:`Design.hash` so that a cache or a calibration
capture can be matched with the design that made it.

Geometry (all derived, all paraxial)
------------------------------------
*Kaleidoscope and relay.* The objective images the scene on the diffuser at the tube's entrance;
the four mirrors make 3×3 virtual copies of the diffuser, each ``tube_width_mm`` wide, all in the
diffuser plane. The relay lens (focal length :math:`f_r`) sits ``relay_gap_mm`` behind the tube's
exit, so the object distance and the image distance on the mask are

.. math:: a = L_{\\text{mirror}} + g_{\\text{relay}}, \\qquad
          \\frac{1}{a} + \\frac{1}{b} = \\frac{1}{f_r}, \\qquad m = \\frac{b}{a} = \\frac{f_r}{a - f_r}.

One view on the mask is :math:`m \\cdot w_{\\text{tube}}` wide; the collimator and the imaging lens
relay the mask to the sensor with magnification :math:`f_{\\text{img}} / f_{\\text{col}}`, so the
view pitch on the sensor is :math:`p_v = m\\, w_{\\text{tube}} f_{\\text{img}} / (f_{\\text{col}}\\,
\\Delta)` pixels (:math:`\\Delta` the pixel pitch). A view's rectangle is :math:`p_v` rounded down
to an even number of pixels (a mask cell covers 2×2 pixels).

*Why the paper's numbers do not close.* With :math:`a = 240` mm and :math:`f_r = 50` mm,
:math:`m = 0.263` and the 3×3 grid is 18.9 mm tall, but the sensor is 2704 × 3.69 µm = 9.98 mm.
The grid fits the sensor height when :math:`3 m w_{\\text{tube}} \\le 9.98` mm, i.e.
:math:`a \\ge 410.8` mm. Keeping the paper's 240 mm mirrors, the ``paper`` preset therefore puts the
relay lens ``relay_gap_mm = 171`` mm behind the tube's exit: the smallest whole millimetre for
which the grid fits (170 mm gives 3 × 903.3 px > 2704 px). A designer sweeping the mirror length
(or the gap) finds the same boundary.

*Dispersion.* :func:`sim.optics.glass.dispersion_px`: the prism sits at minimum deviation for
``prism_center_nm``; band λ lands :math:`\\varphi(\\lambda) = f_{\\text{img}}
\\tan(\\delta(\\lambda_c) - \\delta(\\lambda)) / \\Delta` pixels to the right of the centre band
(longer wavelengths to larger columns).

*Guard stripes.* Views are contiguous on the mask, so each view's dispersed image would spill into
its right-hand neighbour. An opaque stripe ``guard_px`` wide closes the right-hand edge of every
view's code region on the mask (the side towards which the long wavelengths disperse). With the
view's undispersed left edge at column :math:`c_0`, its light covers
:math:`[c_0 + \\varphi_{\\min},\\ c_0 + v - g + \\varphi_{\\max})`; the sensor rectangle starts at
:math:`c_0 + \\lfloor\\varphi_{\\min}\\rfloor` and is :math:`v` wide, which holds all the light when
:math:`g \\ge \\varphi_{\\max} - \\lfloor\\varphi_{\\min}\\rfloor` (the default, rounded up to an even
number of pixels; φ taken at the filter's pass-band edges).

*Mask orientation.* :meth:`Design.mask_pattern` is given as the sensor sees it (the 4f
collimator/imaging relay's inversion already applied): array row ``i`` and column ``j`` map to
sensor row/column ``origin + (i, j) · mask_cell_px`` for the centre band. The mask's centre sits on
the optical axis, which meets the sensor at its centre.

View ids: 0 centre, 1 left, 2 right, 3 top, 4 bottom, 5 top-left, 6 top-right, 7 bottom-left,
8 bottom-right (rows/columns of the 3×3 grid as seen on the sensor).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import typing
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from recon.errors import InputError
from recon.view_ids import VIEW_GRID

__all__ = [
    "Design",
    "PRESETS",
    "VIEW_GRID",
    "VIEW_NAMES",
    "get_design",
    "parse_overrides",
]

VIEW_NAMES: dict[int, str] = {
    0: "centre", 1: "left", 2: "right", 3: "top", 4: "bottom",
    5: "top-left", 6: "top-right", 7: "bottom-left", 8: "bottom-right",
}
#: First-surface mirror materials Mitsuba's ``conductor`` knows (a selection).
MIRROR_MATERIALS = ("Al", "Ag", "Au", "Cu", "Cr")


@dataclass(frozen=True)
class Design:
    """Every physical parameter of the kaleidoscopic CASSI; defaults are the paper's values.

    Lengths in mm unless the name says otherwise (``_um``, ``_px``, ``_nm``). See the module
    docstring for the geometry; :meth:`derived` lists the quantities computed from the fields.
    """

    # diffuser
    diffuser_transmittance: float = 0.85
    # kaleidoscope
    mirror_length_mm: float = 240.0
    tube_width_mm: float = 24.0
    mirror_material: str = "Al"
    relay_gap_mm: float = 171.0
    # lenses
    objective_focal_mm: float = 60.0
    objective_f_number: float = 4.0
    relay_focal_mm: float = 50.0
    collimator_focal_mm: float = 50.0
    imaging_focal_mm: float = 50.0
    #: f/9.1 gives the paper's Airy radius 1.22·λ·N ≈ 6.1 µm ≈ 1.65 px at 550 nm.
    imaging_f_number: float = 9.1
    #: Air-equivalent distance from the collimator to the imaging lens's aperture stop, in units
    #: of the collimator focal length (1: stop at its back focal plane, telecentric on the mask;
    #: smaller values move the entrance pupil toward the tube's exit and vignette the outer views
    #: less; see :mod:`sim.optics.scene`). The paper gives no stop position.
    imaging_stop_fraction: float = 0.5
    # mask
    mask_pitch_um: float = 7.4
    mask_fill: float = 0.5
    mask_seed: int = 0
    mask_size_mm: float = 25.0
    #: Opaque guard stripe width (sensor px); None: the smallest that keeps views apart.
    mask_guard_px: int | None = None
    # prism
    prism_glass: str = "BK7"
    prism_apex_deg: float = 17.0
    prism_center_nm: float = 575.0
    # sensor (Point Grey Grasshopper 3, 9 MP, Sony ICX814; noise figures typical of that sensor)
    sensor_width_px: int = 3376
    sensor_height_px: int = 2704
    sensor_pixel_um: float = 3.69
    bit_depth: int = 12
    full_well_e: float = 14000.0
    read_noise_e: float = 8.0
    qe_curve: str = "mono_cmos"
    exposure_ms: float = 100.0
    # bands
    band_min_nm: float = 450.0
    band_max_nm: float = 700.0
    band_step_nm: float = 10.0
    filter_min_nm: float = 450.0
    filter_max_nm: float = 700.0
    # views
    views: tuple[int, ...] = (0, 1, 2, 3, 4)
    kaleidoscope: bool = True

    # ------------------------------------------------------------------ validation
    def __post_init__(self) -> None:
        hints = _field_types()
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            kind = hints[f.name]
            if kind is float:
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                    raise InputError(f"design field {f.name} must be a finite number, got {v!r}")
                object.__setattr__(self, f.name, float(v))
            elif kind is int or kind == (int | None):
                if v is None and kind != int:
                    continue
                if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                    raise InputError(f"design field {f.name} must be an integer, got {v!r}")
                object.__setattr__(self, f.name, int(v))
            elif kind is bool:
                if not isinstance(v, (bool, np.bool_)):
                    raise InputError(f"design field {f.name} must be true or false, got {v!r}")
                object.__setattr__(self, f.name, bool(v))
            elif kind is str:
                if not isinstance(v, str) or not v:
                    raise InputError(f"design field {f.name} must be a non-empty string, got {v!r}")
            else:  # views
                try:
                    object.__setattr__(self, f.name, tuple(int(x) for x in v))
                except (TypeError, ValueError):
                    raise InputError(f"design field {f.name} must be a list of view ids, got {v!r}") from None
        positive = [
            "mirror_length_mm", "tube_width_mm", "objective_focal_mm", "objective_f_number",
            "relay_focal_mm", "collimator_focal_mm", "imaging_focal_mm", "imaging_f_number",
            "mask_pitch_um", "mask_size_mm", "sensor_pixel_um", "full_well_e", "exposure_ms",
            "band_step_nm", "band_min_nm", "prism_apex_deg", "prism_center_nm",
            "sensor_width_px", "sensor_height_px", "bit_depth",
        ]
        for name in positive:
            if getattr(self, name) <= 0:
                raise InputError(f"design field {name} must be positive, got {getattr(self, name)}")
        if self.relay_gap_mm < 0 or self.read_noise_e < 0 or self.mask_seed < 0:
            raise InputError("relay_gap_mm, read_noise_e and mask_seed must not be negative")
        if not 0.0 < self.imaging_stop_fraction <= 1.0:
            raise InputError("imaging_stop_fraction must lie in (0, 1] (in collimator focal lengths)")
        if not 0.0 < self.diffuser_transmittance <= 1.0:
            raise InputError("diffuser_transmittance must lie in (0, 1]")
        if not 0.0 < self.mask_fill < 1.0:
            raise InputError("mask_fill must lie strictly between 0 and 1")
        if self.bit_depth > 24:
            raise InputError(f"bit_depth must be at most 24, got {self.bit_depth}")
        if self.mask_guard_px is not None and self.mask_guard_px < 0:
            raise InputError("mask_guard_px must be non-negative (or none for automatic)")
        if self.mirror_material not in MIRROR_MATERIALS:
            raise InputError(
                f"mirror_material {self.mirror_material!r} unknown; use one of {', '.join(MIRROR_MATERIALS)}"
            )
        if self.band_max_nm < self.band_min_nm:
            raise InputError("band_max_nm must not be smaller than band_min_nm")
        if not 0 < self.filter_min_nm < self.filter_max_nm:
            raise InputError("the filter pass band needs 0 < filter_min_nm < filter_max_nm")
        if self.band_min_nm < self.filter_min_nm - 1e-9 or self.band_max_nm > self.filter_max_nm + 1e-9:
            raise InputError("the bands must lie inside the filter pass band")
        if not self.filter_min_nm <= self.prism_center_nm <= self.filter_max_nm:
            raise InputError("prism_center_nm must lie inside the filter pass band")
        if not self.views or len(set(self.views)) != len(self.views) or any(
            v not in VIEW_GRID for v in self.views
        ):
            raise InputError(f"views must be distinct ids in 0..8, got {self.views}")
        if not self.kaleidoscope and self.views != (0,):
            object.__setattr__(self, "views", (0,))
        if self.relay_focal_mm >= self.mirror_length_mm + self.relay_gap_mm:
            raise InputError(
                "the relay lens cannot image the diffuser: mirror_length_mm + relay_gap_mm must "
                "exceed relay_focal_mm"
            )
        from sim.optics import glass
        from sim.sensor import QE_CURVES

        if self.qe_curve not in QE_CURVES:
            raise InputError(f"qe_curve {self.qe_curve!r} unknown; use one of {', '.join(QE_CURVES)}")
        glass.get_glass(self.prism_glass)
        # Raises InputError for an impossible apex or total internal reflection in the pass band.
        glass.deviation_rad(
            self.prism_glass, self.prism_apex_deg, self.prism_center_nm,
            np.array([self.filter_min_nm, self.filter_max_nm]),
        )

    # ------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict[str, Any]:
        """All fields as JSON-ready values (tuples become lists)."""
        d = dataclasses.asdict(self)
        d["views"] = list(self.views)
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "Design":
        """A design from :meth:`to_dict` output; unknown keys raise :class:`InputError`."""
        if not isinstance(d, Mapping):
            raise InputError("a design must be a JSON object")
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise InputError(f"unknown design field(s): {', '.join(unknown)}")
        return cls(**dict(d))

    def to_json(self) -> str:
        """Canonical JSON: sorted keys, no whitespace, floats in repr form."""
        return json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))

    @property
    def hash(self) -> str:
        """First 16 hex digits of the SHA-256 of :meth:`to_json`; stable across runs."""
        return hashlib.sha256(self.to_json().encode("utf-8")).hexdigest()[:16]

    def replace(self, **changes: Any) -> "Design":
        """A copy with ``changes`` applied (typed values, validated)."""
        names = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(changes) - names)
        if unknown:
            raise InputError(f"unknown design field(s): {', '.join(unknown)}")
        return dataclasses.replace(self, **changes)

    def with_overrides(self, overrides: Mapping[str, Any] | None) -> "Design":
        """A copy with ``overrides`` applied; string values are parsed to the field's type.

        Raises :class:`InputError` for unknown names or values that do not parse.
        """
        if not overrides:
            return self
        return self.replace(**{k: _parse_value(k, v) for k, v in overrides.items()})

    # ------------------------------------------------------------------ bands
    @property
    def wavelengths(self) -> np.ndarray:
        """Band centres (nm), float64: band_min_nm, band_min_nm + step, … ≤ band_max_nm."""
        n = int(math.floor((self.band_max_nm - self.band_min_nm) / self.band_step_nm + 1e-9)) + 1
        return self.band_min_nm + self.band_step_nm * np.arange(n, dtype=np.float64)

    @property
    def n_bands(self) -> int:
        """Number of bands L."""
        return int(self.wavelengths.size)

    # ------------------------------------------------------------------ relay geometry
    @property
    def object_distance_mm(self) -> float:
        """Relay object distance a (diffuser plane to relay lens).

        With the kaleidoscope, a = mirror_length_mm + relay_gap_mm. Without it the relay is
        refocused so that the single view fills the area of the 3×3 grid:
        a = f_r (1 + 1/m) with m three times the kaleidoscope's minification.
        """
        a = self.mirror_length_mm + self.relay_gap_mm
        if self.kaleidoscope:
            return a
        m = 3.0 * self.relay_focal_mm / (a - self.relay_focal_mm)
        return self.relay_focal_mm * (1.0 + 1.0 / m)

    @property
    def image_distance_mm(self) -> float:
        """Relay image distance b (relay lens to mask): 1/a + 1/b = 1/f_r."""
        a, f = self.object_distance_mm, self.relay_focal_mm
        return a * f / (a - f)

    @property
    def minification(self) -> float:
        """m = b/a = f_r / (a − f_r)."""
        return self.image_distance_mm / self.object_distance_mm

    @property
    def mask_to_sensor(self) -> float:
        """Magnification of the collimator + imaging relay, f_img / f_col."""
        return self.imaging_focal_mm / self.collimator_focal_mm

    @property
    def view_size_mask_mm(self) -> float:
        """Side of one view's image on the mask (mm): m · tube_width_mm."""
        return self.minification * self.tube_width_mm

    @property
    def view_pitch_px(self) -> float:
        """Distance between neighbouring views' centres on the sensor (px, fractional)."""
        return self.view_size_mask_mm * self.mask_to_sensor / (self.sensor_pixel_um * 1e-3)

    @property
    def view_size_px(self) -> int:
        """Side of a view's sensor rectangle: the view pitch rounded down to an even number
        (without the kaleidoscope: the single view, three kaleidoscope pitches wide)."""
        return int(math.floor(self.view_pitch_px / 2.0 + 1e-9)) * 2

    @property
    def grid_size(self) -> int:
        """Views per row/column: 3 with the kaleidoscope, 1 without."""
        return 3 if self.kaleidoscope else 1

    @property
    def mask_cell_px(self) -> float:
        """Side of one mask cell on the sensor (px): pitch · f_img/f_col / pixel (≈ 2)."""
        return self.mask_pitch_um * self.mask_to_sensor / self.sensor_pixel_um

    @property
    def mask_cells(self) -> int:
        """Mask cells along each side of the (square) mask."""
        return int(math.floor(self.mask_size_mm * 1e3 / self.mask_pitch_um + 1e-9))

    @property
    def mask_origin_px(self) -> tuple[float, float]:
        """Sensor (row, col) of the top-left corner of mask cell (0, 0), centre band."""
        half = 0.5 * self.mask_cells * self.mask_cell_px
        return (0.5 * self.sensor_height_px - half, 0.5 * self.sensor_width_px - half)

    # ------------------------------------------------------------------ dispersion and blur
    def dispersion_px_at(self, wavelength_nm) -> np.ndarray:
        """φ(λ) in px relative to ``prism_center_nm`` (positive: towards larger columns)."""
        from sim.optics.glass import dispersion_px

        return dispersion_px(self, wavelength_nm)

    @property
    def dispersion_px(self) -> np.ndarray:
        """φ(λ_l) of every band, px, relative to the centre wavelength."""
        return self.dispersion_px_at(self.wavelengths)

    @property
    def dispersion_range_px(self) -> tuple[float, float]:
        """(φ_min, φ_max) at the filter's pass-band edges: where any light can land."""
        lo, hi = self.dispersion_px_at(np.array([self.filter_min_nm, self.filter_max_nm]))
        return float(lo), float(hi)

    @property
    def dispersion_span_px(self) -> float:
        """φ(filter_max_nm) − φ(filter_min_nm), px."""
        lo, hi = self.dispersion_range_px
        return hi - lo

    @property
    def guard_px(self) -> int:
        """The guard stripe actually used: ``mask_guard_px`` or the automatic width."""
        if self.mask_guard_px is not None:
            return int(self.mask_guard_px)
        lo, hi = self.dispersion_range_px
        need = math.ceil(hi - math.floor(lo) - 1e-9)
        return int(need + (need % 2))

    def airy_radius_um(self, wavelength_nm) -> np.ndarray:
        """Airy radius R = 1.22·λ·N at the sensor (µm), N = imaging_f_number (= L/d)."""
        return 1.22 * np.asarray(wavelength_nm, dtype=np.float64) * 1e-3 * self.imaging_f_number

    @property
    def airy_radius_px(self) -> float:
        """Airy radius at ``prism_center_nm``, in pixels."""
        return float(self.airy_radius_um(self.prism_center_nm)) / self.sensor_pixel_um

    # ------------------------------------------------------------------ views on the sensor
    def _view_origin_undispersed(self, view: int) -> tuple[int, int]:
        """(row, col) of the view's top-left corner on the sensor, centre band, no guard shift."""
        r, c = VIEW_GRID[view] if self.kaleidoscope else (1, 1)
        pitch, v = self.view_pitch_px, self.view_size_px
        row = 0.5 * self.sensor_height_px + (r - 1) * pitch - 0.5 * v
        col = 0.5 * self.sensor_width_px + (c - 1) * pitch - 0.5 * v
        return int(round(row)), int(round(col))

    def code_region_px(self, view: int) -> tuple[int, int, int, int]:
        """(row0, col0, height, width) of the view's random-code region on the sensor, as
        imaged at the centre band: the view minus the guard stripe on its right-hand side."""
        if view not in VIEW_GRID or (not self.kaleidoscope and view != 0):
            raise InputError(f"no view {view} in this design")
        row, col = self._view_origin_undispersed(view)
        v = self.view_size_px
        return row, col, v, max(v - self.guard_px, 0)

    def view_rect(self, view: int) -> tuple[int, int, int, int]:
        """(row0, col0, height, width) of the view's rectangle on the sensor (all its light)."""
        row, col, v, _ = self.code_region_px(view)
        lo, _ = self.dispersion_range_px
        return row, col + int(math.floor(lo)), v, v

    def view_rects(self) -> dict[int, tuple[int, int, int, int]]:
        """:meth:`view_rect` of every view in the grid (all 9, or view 0 alone)."""
        ids = range(9) if self.kaleidoscope else (0,)
        return {v: self.view_rect(v) for v in ids}

    def view_flips(self, view: int) -> tuple[bool, bool]:
        """(vertical, horizontal) mirror flip of the view relative to the centre view."""
        r, c = VIEW_GRID[view]
        return (r != 1, c != 1)

    def light_extent_px(self, view: int) -> tuple[float, float, float, float]:
        """(row0, col0, row1, col1) bounds of where the view's light lands (pass band)."""
        row, col, v, w = self.code_region_px(view)
        lo, hi = self.dispersion_range_px
        return float(row), col + lo, float(row + v), col + w + hi

    @property
    def views_fit(self) -> bool:
        """True when every view's light lands inside the sensor and inside its own rectangle
        (so the rectangles neither overlap nor leave the sensor)."""
        H, W = self.sensor_height_px, self.sensor_width_px
        rects = self.view_rects()
        for v, (r0, c0, h, w) in rects.items():
            if r0 < 0 or c0 < 0 or r0 + h > H or c0 + w > W or h <= 0:
                return False
            lr0, lc0, lr1, lc1 = self.light_extent_px(v)
            if lc0 < c0 - 1e-9 or lc1 > c0 + w + 1e-9 or lr0 < r0 or lr1 > r0 + h:
                return False
        boxes = list(rects.values())
        for i in range(len(boxes)):
            for j in range(i + 1, len(boxes)):
                a, b = boxes[i], boxes[j]
                if (a[0] < b[0] + b[2] and b[0] < a[0] + a[2]
                        and a[1] < b[1] + b[3] and b[1] < a[1] + a[3]):
                    return False
        return True

    @property
    def grid_fits_sensor_height(self) -> bool:
        """Whether grid_size view pitches fit the sensor height (the relay-gap criterion)."""
        return self.grid_size * self.view_pitch_px <= self.sensor_height_px + 1e-9

    # ------------------------------------------------------------------ mask
    def mask_owner(self) -> np.ndarray:
        """Which view's code region holds each mask cell (by the cell's centre), as the sensor
        sees it.

        Returns
        -------
        numpy.ndarray
            int8, shape (mask_cells, mask_cells): the view id, or −1 for cells in no code
            region (guard stripes, the thin gaps between views and the field stop around the
            grid, all chrome).  Cell (i, j) is imaged (centre band) onto sensor rows/cols
            ``mask_origin_px + (i, j)·mask_cell_px``.
        """
        n = self.mask_cells
        r0, c0 = self.mask_origin_px
        centres = (np.arange(n, dtype=np.float64) + 0.5) * self.mask_cell_px
        rows, cols = r0 + centres, c0 + centres
        owner = np.full((n, n), -1, dtype=np.int8)
        for v in (range(9) if self.kaleidoscope else (0,)):
            vr, vc, h, w = self.code_region_px(v)
            rin = np.flatnonzero((rows >= vr) & (rows < vr + h))
            cin = np.flatnonzero((cols >= vc) & (cols < vc + w))
            if rin.size and cin.size:
                owner[rin[0]:rin[-1] + 1, cin[0]:cin[-1] + 1] = v
        return owner

    def mask_pattern(self) -> np.ndarray:
        """The binary mask over the whole mask area, in mask cells, as the sensor sees it.

        Returns
        -------
        numpy.ndarray
            bool, shape (mask_cells, mask_cells); True = open (quartz), False = chrome. Cells
            inside a view's code region (:meth:`mask_owner`) are open with probability
            ``mask_fill`` (a ``numpy.random.default_rng(mask_seed)`` draw over the whole mask,
            so the pattern of one view does not depend on the others); guard stripes, the thin
            gaps between views and everything outside the grid (a field stop) are chrome.
        """
        n = self.mask_cells
        rng = np.random.default_rng(self.mask_seed)
        code = rng.random((n, n), dtype=np.float32) < np.float32(self.mask_fill)
        return code & (self.mask_owner() >= 0)

    # ------------------------------------------------------------------ radiometry helpers
    @property
    def pixel_area_m2(self) -> float:
        """Pixel area (m²)."""
        return (self.sensor_pixel_um * 1e-6) ** 2

    @property
    def max_dn(self) -> int:
        """Largest ADC code, 2**bit_depth − 1."""
        return (1 << self.bit_depth) - 1

    @property
    def gain_e_per_dn(self) -> float:
        """The ADC's conversion gain (e⁻/DN): the full well reads as the top code."""
        return float(self.full_well_e) / self.max_dn

    # ------------------------------------------------------------------ summary
    def derived(self) -> dict[str, Any]:
        """Derived quantities as a JSON-ready dict (see the module docstring for the formulas)."""
        lo, hi = self.dispersion_range_px
        disp = self.dispersion_px
        from sim.optics.glass import apex_for_span

        try:
            apex60 = apex_for_span(
                self.prism_glass, 60.0, self.filter_min_nm, self.filter_max_nm,
                self.prism_center_nm, self.imaging_focal_mm, self.sensor_pixel_um,
            )
        except InputError:
            apex60 = None
        return {
            "hash": self.hash,
            "wavelengths_nm": [float(x) for x in self.wavelengths],
            "n_bands": self.n_bands,
            "object_distance_mm": self.object_distance_mm,
            "image_distance_mm": self.image_distance_mm,
            "minification": self.minification,
            "mask_to_sensor": self.mask_to_sensor,
            "view_size_mask_mm": self.view_size_mask_mm,
            "grid_size_mask_mm": self.grid_size * self.view_size_mask_mm,
            "sensor_size_mm": [self.sensor_height_px * self.sensor_pixel_um * 1e-3,
                               self.sensor_width_px * self.sensor_pixel_um * 1e-3],
            "view_pitch_px": self.view_pitch_px,
            "view_size_px": self.view_size_px,
            "mask_cell_px": self.mask_cell_px,
            "mask_cells": self.mask_cells,
            "mask_origin_px": list(self.mask_origin_px),
            "dispersion_px": [float(x) for x in disp],
            "dispersion_step_px": [float(x) for x in np.diff(disp)],
            "dispersion_range_px": [lo, hi],
            "dispersion_span_px": hi - lo,
            "apex_for_60px_deg": apex60,
            "guard_px": self.guard_px,
            "airy_radius_um": float(self.airy_radius_um(self.prism_center_nm)),
            "airy_radius_px": self.airy_radius_px,
            "view_rects": {str(k): list(v) for k, v in self.view_rects().items()},
            "views_used": list(self.views),
            "grid_fits_sensor_height": self.grid_fits_sensor_height,
            "views_fit": self.views_fit,
        }


# ---------------------------------------------------------------------- field types and parsing
_TYPES: dict[str, Any] | None = None


def _field_types() -> dict[str, Any]:
    global _TYPES
    if _TYPES is None:
        hints = typing.get_type_hints(Design)
        _TYPES = {f.name: hints[f.name] for f in dataclasses.fields(Design)}
    return _TYPES


_TRUE = {"1", "true", "yes", "on", "y", "t"}
_FALSE = {"0", "false", "no", "off", "n", "f"}


def _parse_value(name: str, value: Any) -> Any:
    """Parse ``value`` (a string from the command line, or an already typed value) for field
    ``name``; raise :class:`InputError` with a one-line reason when it cannot be used."""
    types = _field_types()
    if name not in types:
        raise InputError(f"unknown design field {name!r}")
    if not isinstance(value, str):
        return value
    kind, s = types[name], value.strip()
    try:
        if kind is float:
            x = float(s)
            if not math.isfinite(x):
                raise ValueError
            return x
        if kind is int:
            return int(s)
        if kind == (int | None):
            return None if s.lower() in {"none", "auto", "null", ""} else int(s)
        if kind is bool:
            if s.lower() in _TRUE:
                return True
            if s.lower() in _FALSE:
                return False
            raise ValueError
        if kind is str:
            return s
        # tuple of view ids: "0,1,2", "[0, 1, 2]" or "0 1 2"
        parts = s.strip("[]() ").replace(",", " ").split()
        return tuple(int(p) for p in parts)
    except ValueError:
        raise InputError(f"bad value {value!r} for design field {name}") from None


def parse_overrides(items: list[str] | tuple[str, ...] | None) -> dict[str, str]:
    """``["k=v", …]`` → ``{"k": "v"}``; a missing ``=`` or an empty name raises InputError."""
    out: dict[str, str] = {}
    for item in items or ():
        if "=" not in item:
            raise InputError(f"override {item!r} is not of the form name=value")
        k, v = item.split("=", 1)
        if not k.strip():
            raise InputError(f"override {item!r} has no field name")
        out[k.strip()] = v
    return out


# ---------------------------------------------------------------------- presets
def _small() -> Design:
    """A scaled design for tests and demos (renders end to end in seconds).

    The paper's optics with a coarse 600×480 sensor of 20 µm pixels (the mask cell, 40 µm, still
    covers 2×2 pixels) and 11 bands (450–700 nm, step 25 nm). The relay gap, 186 mm, is the
    smallest whole millimetre after 185 mm (where the grid would exactly touch the sensor
    edges) for which the 3×3 grid fits 480 px; views are 158 px. The 30° BK-7 prism spreads
    450–700 nm over ~17 px, so adjacent 25 nm bands are ~1.7 px apart on average (2.6 px in
    the blue, 1.2 px in the red: prism dispersion is not linear).
    """
    return Design(
        relay_gap_mm=186.0,
        mask_pitch_um=40.0,
        mask_size_mm=12.5,
        prism_apex_deg=30.0,
        sensor_width_px=600,
        sensor_height_px=480,
        sensor_pixel_um=20.0,
        full_well_e=14000.0,
        band_step_nm=25.0,
    )


PRESETS: dict[str, Design] = {"paper": Design(), "small": _small()}


def get_design(name: str = "paper", overrides: Mapping[str, Any] | None = None) -> Design:
    """The preset ``name`` (``paper`` or ``small``) with ``overrides`` applied."""
    if name not in PRESETS:
        raise InputError(f"unknown design preset {name!r}; known: {', '.join(PRESETS)}")
    return PRESETS[name].with_overrides(overrides)
