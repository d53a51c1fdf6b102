"""Measuring a design in its own renders: view size and position, gaps, vignetting, dispersion.

The design formulas (:mod:`sim.optics.design`, :mod:`sim.optics.glass`) *predict* where light lands; this
module *measures* it in monochromatic renders of the physical simulator (Mitsuba's path tracer,
:func:`sim.optics.render.render_direct`) passed through the sensor model (:func:`sim.sensor.capture`:
Airy blur, shot and read noise, 12-bit ADC), so a design sweep can put the two side by side.

Coordinates
-----------
Positions are continuous sensor coordinates: pixel ``k`` covers ``[k, k + 1)`` and its centre
is ``k + 0.5`` (so a view rectangle's ``col0`` is the left edge of its first pixel).

Targets (monochromatic, on the diffuser; one texel = one sensor pixel of the centre view)
------------------------------------------------------------------------------------------
*Vertical line pair* at texel columns :math:`c_1` and :math:`c_2 = v - 1 - c_1`, symmetric about
the tube axis, with :math:`c_1 \\ge g` (the guard width) so both lines fall inside the open code
region of the centre view *and* of the mirrored left/right copies. *Horizontal line pair* at rows
:math:`r_1` and :math:`v - 1 - r_1`. The midpoint of a pair is the image of the tube axis in
every copy, mirrored or not, so

.. math:: p_x = \\tfrac12 (\\bar x_{\\text{right}} - \\bar x_{\\text{left}}), \\qquad
          p_y = \\tfrac12 (\\bar y_{\\text{bottom}} - \\bar y_{\\text{top}})

are the measured view pitches: the image of one tube width :math:`w` on the sensor, the quantity
the design predicts as :math:`p_v = m\\, w\\, f_{\\text{img}} / (f_{\\text{col}} \\Delta)` with
:math:`m = b/a`, :math:`1/a + 1/b = 1/f_r`. Inside one view the pair's separation gives the
measured minification,

.. math:: m_{\\text{meas}} = \\frac{(x_2 - x_1)\\, \\Delta}{M\\, (c_2 - c_1)\\, t},

with :math:`t` the texel size on the diffuser (mm) and :math:`M = f_{\\text{img}}/f_{\\text{col}}`.

*Dispersion.* The vertical pair rendered at each wavelength in the centre view moves by
:math:`\\varphi(\\lambda)`; the measured span is :math:`\\bar x(\\lambda_{\\max}) -
\\bar x(\\lambda_{\\min})` at the filter's edges, compared with Sellmeier + prism geometry
(:func:`sim.optics.glass.dispersion_px`).

*White target.* A uniform cube rendered with every code cell open (:func:`open_code_mask`: the
design's mask without its random code, guard stripes and field stop kept) at the filter's two
edges and at the prism's centre wavelength gives each copy's lit extent (edges at half the
copy's plateau, sub-pixel by linear interpolation), hence the gaps between neighbouring copies
(left edges at :math:`\\lambda_{\\min}`, right edges at :math:`\\lambda_{\\max}`: negative gaps are
overlaps), whether a copy is cut by the sensor's border, and vignetting: each copy's mean
throughput relative to the centre copy and its worst edge fall-off
:math:`1 - \\min(\\text{edge strips}) / \\text{median}`.

Every render is deterministic (fixed sampler and noise seeds).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from recon.errors import InputError

__all__ = [
    "centroid",
    "peak_centroids",
    "lit_runs",
    "open_code_mask",
    "line_pair",
    "target_cube",
    "render_mono",
    "measure_geometry",
    "measure_dispersion",
    "measure_white",
    "predicted",
    "measure_all",
]


# ---------------------------------------------------------------------- 1-D profile analysis
def centroid(profile: np.ndarray, lo: int, hi: int, background: float = 0.0) -> float:
    """Sub-pixel centroid of ``profile[lo:hi]`` above ``background``.

    .. math:: \\bar x = \\frac{\\sum_k (k + \\tfrac12)\\, \\max(p_k - b, 0)}{\\sum_k \\max(p_k - b, 0)}

    in the pixel-edge coordinates of the module (pixel k's centre at k + 0.5). NaN when the
    window holds no signal.
    """
    p = np.asarray(profile, dtype=np.float64)
    lo, hi = max(int(lo), 0), min(int(hi), p.size)
    w = np.maximum(p[lo:hi] - background, 0.0)
    s = float(w.sum())
    if hi <= lo or s <= 0.0:
        return float("nan")
    return float(np.dot(np.arange(lo, hi) + 0.5, w) / s)


def peak_centroids(profile: np.ndarray, n: int, half_width: int = 4,
                   min_separation: int = 3) -> list[float]:
    """Centroids of the ``n`` strongest peaks of a 1-D profile, left to right.

    The background is the profile's median (thin lines on a dark field); each peak's centroid is
    taken over ``±half_width`` pixels around its maximum, and pixels within ``min_separation``
    + ``half_width`` of a found peak are excluded from the next search. Returns fewer than ``n``
    values when the profile holds fewer peaks above the background noise.
    """
    p = np.asarray(profile, dtype=np.float64).copy()
    if p.size == 0:
        return []
    bg = float(np.median(p))
    noise = float(np.median(np.abs(p - bg))) * 1.4826 + 1e-12
    work = p - bg
    out = []
    for _ in range(int(n)):
        k = int(np.argmax(work))
        if not work[k] > 8.0 * noise:
            break
        out.append(centroid(p, k - half_width, k + half_width + 1, bg))
        r = half_width + int(min_separation)
        work[max(k - r, 0):k + r + 1] = -np.inf
    return sorted(out)


def _crossing(p: np.ndarray, i: int, level: float) -> float:
    """Sub-pixel position where the profile crosses ``level`` between pixel i−1 and pixel i
    (pixel centres at k + 0.5), by linear interpolation."""
    a, b = float(p[i - 1]), float(p[i])
    t = 0.5 if b == a else (level - a) / (b - a)
    return i - 0.5 + float(np.clip(t, 0.0, 1.0))


def lit_runs(profile: np.ndarray, level: float) -> list[tuple[float, float]]:
    """Sub-pixel (start, end) edges of the runs where ``profile`` ≥ ``level``.

    Edges are at the interpolated crossings of ``level``; a run touching the profile's end gets
    that end (0 or ``size``) as its edge.
    """
    p = np.asarray(profile, dtype=np.float64)
    on = p >= level
    if not on.any():
        return []
    d = np.diff(on.astype(np.int8))
    starts = list(np.flatnonzero(d == 1) + 1)
    ends = list(np.flatnonzero(d == -1) + 1)
    if on[0]:
        starts.insert(0, 0)
    if on[-1]:
        ends.append(p.size)
    runs = []
    for s, e in zip(starts, ends):
        x0 = 0.0 if s == 0 else _crossing(p, s, level)
        x1 = float(p.size) if e == p.size else _crossing(p, e, level)
        runs.append((x0, x1))
    return runs


# ---------------------------------------------------------------------- targets and renders
def open_code_mask(design) -> np.ndarray:
    """The design's mask with every code cell open: guard stripes, the gaps between views and
    the field stop stay chrome.

    Uses :meth:`Design.mask_pattern` itself (so the open area is exactly the design's): with a
    fill factor whose float32 value is 1.0, every cell's uniform draw in [0, 1) is below it.
    """
    fill = 1.0 - 1e-12
    assert np.float32(fill) == np.float32(1.0)
    return design.replace(mask_fill=fill).mask_pattern()


@dataclass(frozen=True)
class LinePair:
    """Texel positions of the vertical (columns) and horizontal (rows) line pairs."""

    cols: tuple[int, int]
    rows: tuple[int, int]


def line_pair(design) -> LinePair:
    """The line-pair target for ``design`` (see the module notes).

    Columns: :math:`c_1 = g + 2`, :math:`c_2 = v - 1 - c_1` (as far apart as the open part of
    both the view and its mirror image allows, a mask cell clear of the guard); rows
    :math:`r_1 = \\lfloor v/4 \\rceil`, :math:`r_2 = v - 1 - r_1`. Raises :class:`InputError`
    when the guard leaves no room for a pair visible in the mirrored copies (v − 2g < 8).
    """
    v, g = design.view_size_px, design.guard_px
    if v < 8 or v - 2 * g < 8:
        raise InputError(
            f"views of {v} px with a {g} px guard stripe leave no room for a line-pair target"
        )
    c1 = g + 2
    r1 = int(round(v / 4.0))
    return LinePair(cols=(c1, v - 1 - c1), rows=(r1, v - 1 - r1))


def target_cube(design, kind: str) -> np.ndarray:
    """A one-band (v, v) float32 target: ``"vlines"``, ``"hlines"`` (the line pairs, value 1 on
    0) or ``"white"`` (all 1)."""
    v = design.view_size_px
    img = np.zeros((v, v), dtype=np.float32)
    if kind == "white":
        img[:] = 1.0
    else:
        lp = line_pair(design)
        if kind == "vlines":
            img[:, list(lp.cols)] = 1.0
        elif kind == "hlines":
            img[list(lp.rows), :] = 1.0
        else:
            raise InputError(f"unknown target {kind!r}")
    return img


def _clip_window(design, r0, c0, h, w):
    H, W = design.sensor_height_px, design.sensor_width_px
    r1, c1 = min(r0 + h, H), min(c0 + w, W)
    r0, c0 = max(r0, 0), max(c0, 0)
    if r1 <= r0 or c1 <= c0:
        return None
    return (int(r0), int(c0), int(r1 - r0), int(c1 - c0))


def render_mono(design, target: np.ndarray, wavelength_nm: float, *, windows=None,
                mask: np.ndarray | None = None, spp: int = 8, seed: int = 0,
                sensor: bool = True) -> np.ndarray:
    """A monochromatic capture (Hs, Ws) float32 of a one-band target on the diffuser.

    Parameters
    ----------
    design : sim.optics.design.Design
    target : ndarray (H, W)
        Radiance on the diffuser (relative units), placed like a scene cube.
    wavelength_nm : float
        The single wavelength rendered (a delta line, as a monochromator gives).
    windows : list of (row0, col0, h, w), optional
        Sensor windows to render (clipped to the sensor); the whole sensor by default.
    mask : ndarray of bool, optional
        Mask pattern; :func:`open_code_mask` by default.
    spp : int
        Samples per pixel (pixel area × lens aperture).
    seed : int
        Sampler and noise seed.
    sensor : bool
        Pass the irradiance through :func:`sim.sensor.capture` (Airy blur, noise, ADC, exposed
        to 80 % of the full well at the brightest pixel) and return DN; otherwise return the
        noise-free irradiance.
    """
    from sim.optics.render import render_direct

    lam = float(wavelength_nm)
    if windows is None:
        windows = [(0, 0, design.sensor_height_px, design.sensor_width_px)]
    wins = [w for w in (_clip_window(design, *win) for win in windows) if w is not None]
    if mask is None:
        mask = open_code_mask(design)
    cube = np.asarray(target, dtype=np.float32)[:, :, None]
    irr = render_direct(design, cube, [lam], spp=int(spp), seed=int(seed), intervals=[[lam, lam]],
                        windows=wins, mask_pattern=mask, progress=False)[0]
    if not sensor:
        return irr
    from sim.sensor import capture

    if not float(irr.max()) > 0.0:
        return np.zeros_like(irr)
    return capture(irr[:, :, None], design, [lam], seed=seed, diffraction=True, noise=True,
                   auto_exposure=0.8)


# ---------------------------------------------------------------------- predictions
def _view_centre(design, view: int) -> tuple[float, float]:
    """Predicted (row, col) of the image of the tube axis in copy ``view`` at λ_c."""
    from sim.optics.design import VIEW_GRID

    r, c = VIEW_GRID[view]
    p = design.view_pitch_px
    return (0.5 * design.sensor_height_px + (r - 1) * p, 0.5 * design.sensor_width_px + (c - 1) * p)


def predicted(design) -> dict:
    """The design's own predictions of everything :func:`measure_all` measures (JSON-ready).

    ``gap_x_px``/``gap_y_px``: the smallest gap between neighbouring copies' light
    (:meth:`Design.light_extent_px`, over the pass band), negative for an overlap.
    """
    from sim.optics.design import VIEW_GRID

    lo, hi = design.dispersion_range_px
    ext = {v: design.light_extent_px(v) for v in range(9)}
    at = {VIEW_GRID[v]: v for v in range(9)}
    gx = min(ext[at[(r, c + 1)]][1] - ext[at[(r, c)]][3] for r in range(3) for c in range(2))
    gy = min(ext[at[(r + 1, c)]][0] - ext[at[(r, c)]][2] for r in range(2) for c in range(3))
    return {
        "minification": design.minification,
        "view_size_px": design.view_pitch_px,
        "view_rect_px": design.view_size_px,
        "dispersion_span_px": design.dispersion_span_px,
        "gap_x_px": float(gx),
        "gap_y_px": float(gy),
        "views_fit": bool(design.views_fit),
    }


# ---------------------------------------------------------------------- measurements
def _lines_in(img: np.ndarray, win, axis: int, n: int = 2, sep: int = 9) -> list[float]:
    """Centroids (sensor coordinates) of ``n`` lines ``sep`` px apart in window ``win`` of
    ``img``; axis 1: vertical lines (positions along columns), axis 0: horizontal lines."""
    r0, c0, h, w = win
    sub = img[r0:r0 + h, c0:c0 + w].astype(np.float64)
    prof = sub.sum(axis=0) if axis == 1 else sub.sum(axis=1)
    # Centroid windows narrower than half the separation keep the two lines apart.
    hw = int(max(1, min(4, (sep - 1) // 2)))
    found = peak_centroids(prof, n, half_width=hw, min_separation=0)
    off = c0 if axis == 1 else r0
    return [x + off for x in found]


def _pair_windows(design, views, margin: int) -> dict[int, tuple]:
    """Sensor window around each copy (its light over the pass band, with a margin)."""
    out = {}
    for v in views:
        r0, c0, r1, c1 = design.light_extent_px(v)
        win = _clip_window(design, int(math.floor(r0)) - margin, int(math.floor(c0)) - margin,
                           int(math.ceil(r1 - r0)) + 2 * margin, int(math.ceil(c1 - c0)) + 2 * margin)
        if win is not None:
            out[v] = win
    return out


def measure_geometry(design, *, spp: int = 8, seed: int = 0) -> dict:
    """View pitch (the measured view size), minification and view position from the line pairs
    at the prism's centre wavelength (module notes). NaN where a copy is off the sensor."""
    from sim.optics.diffuser import cube_region

    lam = design.prism_center_nm
    lp = line_pair(design)
    wins = _pair_windows(design, range(5), margin=3)
    vimg = render_mono(design, target_cube(design, "vlines"), lam, windows=list(wins.values()),
                       spp=spp, seed=seed)
    himg = render_mono(design, target_cube(design, "hlines"), lam, windows=list(wins.values()),
                       spp=spp, seed=seed + 1)
    sx, sy = lp.cols[1] - lp.cols[0], lp.rows[1] - lp.rows[0]
    xs = {v: _lines_in(vimg, w, axis=1, sep=sx) for v, w in wins.items()}
    ys = {v: _lines_in(himg, w, axis=0, sep=sy) for v, w in wins.items()}
    nan = float("nan")

    def mid(d, v):
        return float(np.mean(d[v])) if len(d.get(v, [])) == 2 else nan

    px = 0.5 * (mid(xs, 2) - mid(xs, 1))
    py = 0.5 * (mid(ys, 4) - mid(ys, 3))
    tex = cube_region(design, (design.view_size_px,) * 2).dx
    M, pix_mm = design.mask_to_sensor, design.sensor_pixel_um * 1e-3
    sep_x = xs[0][1] - xs[0][0] if len(xs.get(0, [])) == 2 else nan
    sep_y = ys[0][1] - ys[0][0] if len(ys.get(0, [])) == 2 else nan
    m_x = sep_x * pix_mm / (M * (lp.cols[1] - lp.cols[0]) * tex)
    m_y = sep_y * pix_mm / (M * (lp.rows[1] - lp.rows[0]) * tex)
    pitches = [p for p in (px, py) if np.isfinite(p)]
    cy, cx = _view_centre(design, 0)
    return {
        "view_pitch_x_px": px,
        "view_pitch_y_px": py,
        # The pitch is the image of one tube width; when the outer copies are off the sensor,
        # fall back to the in-view scale times the tube width.
        "view_size_px": float(np.mean(pitches)) if pitches else
        float(np.nanmean([m_x, m_y])) * design.tube_width_mm * M / pix_mm,
        "minification_x": float(m_x),
        "minification_y": float(m_y),
        "minification": float(np.nanmean([m_x, m_y])) if np.isfinite([m_x, m_y]).any() else nan,
        "view_centre_err_px": [mid(ys, 0) - cy, mid(xs, 0) - cx],
        "lines_found": {str(v): [len(xs.get(v, [])), len(ys.get(v, []))] for v in range(5)},
    }


def measure_dispersion(design, wavelengths=None, *, spp: int = 8, seed: int = 0) -> dict:
    """φ(λ) of the centre view's vertical line pair, measured at each wavelength.

    ``wavelengths``: the filter's edges, the prism's centre wavelength and the band centres by
    default. Returns the wavelengths, measured and predicted φ (px, relative to the measured
    and predicted position at ``prism_center_nm``), the measured and predicted span between the
    filter's edges, and the largest per-wavelength disagreement.
    """
    from sim.optics.glass import dispersion_px

    lam_c = design.prism_center_nm
    if wavelengths is None:
        wavelengths = np.concatenate([[design.filter_min_nm, lam_c, design.filter_max_nm],
                                      design.wavelengths])
    wl = np.unique(np.round(np.asarray(wavelengths, dtype=np.float64), 6))
    if lam_c not in wl:
        wl = np.unique(np.append(wl, lam_c))
    win = _pair_windows(design, [0], margin=4)[0]
    # The line pair's rows need not all be rendered: a central strip keeps the cost down while
    # still averaging many mask-free rows.
    r0, c0, h, w = win
    strip = max(16, h // 3)
    win = (r0 + (h - strip) // 2, c0, strip, w)
    target = target_cube(design, "vlines")
    lp = line_pair(design)
    pos = []
    for i, lam in enumerate(wl):
        img = render_mono(design, target, lam, windows=[win], spp=spp, seed=seed + 10 + i)
        found = _lines_in(img, win, axis=1, sep=lp.cols[1] - lp.cols[0])
        pos.append(float(np.mean(found)) if len(found) == 2 else float("nan"))
    pos = np.array(pos)
    x_c = pos[int(np.flatnonzero(wl == lam_c)[0])]
    phi_meas = pos - x_c
    phi_pred = dispersion_px(design, wl)
    i_lo = int(np.argmin(np.abs(wl - design.filter_min_nm)))
    i_hi = int(np.argmin(np.abs(wl - design.filter_max_nm)))
    return {
        "wavelengths_nm": wl.tolist(),
        "phi_meas_px": phi_meas.tolist(),
        "phi_pred_px": phi_pred.tolist(),
        "span_meas_px": float(pos[i_hi] - pos[i_lo]),
        "span_pred_px": float(phi_pred[i_hi] - phi_pred[i_lo]),
        "max_phi_err_px": (float(np.nanmax(np.abs(phi_meas - phi_pred)))
                           if np.isfinite(phi_meas).any() else float("nan")),
        "centre_x_err_px": float(x_c - _view_centre(design, 0)[1]),
    }


def _copy_extents(img: np.ndarray, design, axis: int,
                  shift: float = 0.0) -> dict[int, tuple[float, float]]:
    """Lit extent (sub-pixel, half the plateau) of every copy along ``axis`` (1: columns, in the
    copy's central rows; 0: rows, in its central columns). ``shift``: the predicted dispersion
    shift of the capture's wavelength, which only centres the search window on the copy."""
    out = {}
    H, W = img.shape
    v_px, g = design.view_size_px, design.guard_px
    for v in range(9):
        cy, cx = _view_centre(design, v)
        q = 0.25 * v_px
        if axis == 1:
            a, b = int(round(cy - q)), int(round(cy + q))
            if b <= 0 or a >= H:
                continue
            prof = img[max(a, 0):min(b, H)].mean(axis=0)
            # The guard closes the right-hand g px: the code region's centre is left of the axis.
            centre, n = cx - 0.5 * g + shift, W
        else:
            a, b = int(round(cx - q)), int(round(cx + q))
            if b <= 0 or a >= W:
                continue
            prof = img[:, max(a, 0):min(b, W)].mean(axis=1)
            centre, n = cy, H
        # Search a pitch and a half around the copy; keep the lit run that holds its centre.
        half = 0.75 * design.view_pitch_px
        s, e = int(max(math.floor(centre - half), 0)), int(min(math.ceil(centre + half), n))
        if e - s < 4 or not s <= centre < e:
            continue
        seg = prof[s:e]
        plateau = float(np.percentile(seg, 90))
        if plateau <= 0:
            continue
        own = [r for r in lit_runs(seg, 0.5 * plateau) if r[0] <= centre - s <= r[1]]
        if own:
            # Copies that touch merge into one run: a copy ends at most half a pitch from its
            # centre (where its neighbour's begins).
            p2 = 0.5 * design.view_pitch_px
            out[v] = (max(own[0][0] + s, centre - p2), min(own[0][1] + s, centre + p2))
    return out


def _clipped_copies(img: np.ndarray, design, level: float = 0.05) -> list[int]:
    """Copies whose light reaches the sensor's border (or misses the sensor entirely).

    A copy counts as cut when its code region runs past the border and the border row/column
    inside it is lit at more than ``level`` of the copy's median (vignetting may dim the edge,
    so a lit-extent threshold alone would miss it).
    """
    H, W = img.shape
    out = []
    for v in range(9):
        r0, c0, h, w = design.code_region_px(v)
        win = _clip_window(design, r0, c0, h, w)
        if win is None:
            out.append(v)
            continue
        a, b, hh, ww = win
        sub = img[a:a + hh, b:b + ww].astype(np.float64)
        lit = sub[sub > 0]
        if lit.size == 0:
            out.append(v)
            continue
        ref = level * float(np.median(lit))
        edges = []
        if r0 < 0:
            edges.append(sub[0])
        if r0 + h > H:
            edges.append(sub[-1])
        if c0 < 0:
            edges.append(sub[:, 0])
        if c0 + w > W:
            edges.append(sub[:, -1])
        if any(float(e.mean()) > ref for e in edges):
            out.append(v)
    return out


def measure_white(design, *, spp: int = 4, seed: int = 0) -> dict:
    """Gaps/overlaps between copies, clipping by the sensor, and vignetting (module notes)."""
    from sim.optics.design import VIEW_GRID

    white = target_cube(design, "white")
    lo_img = render_mono(design, white, design.filter_min_nm, spp=spp, seed=seed + 100)
    hi_img = render_mono(design, white, design.filter_max_nm, spp=spp, seed=seed + 101)
    c_img = render_mono(design, white, design.prism_center_nm, spp=spp, seed=seed + 102,
                        sensor=False)
    at = {VIEW_GRID[v]: v for v in range(9)}
    lo, hi = design.dispersion_range_px
    left = _copy_extents(lo_img, design, axis=1, shift=lo)
    right = _copy_extents(hi_img, design, axis=1, shift=hi)
    rows = _copy_extents(c_img, design, axis=0)
    gx = [left[at[(r, c + 1)]][0] - right[at[(r, c)]][1] for r in range(3) for c in range(2)
          if at[(r, c + 1)] in left and at[(r, c)] in right]
    gy = [rows[at[(r + 1, c)]][0] - rows[at[(r, c)]][1] for r in range(2) for c in range(3)
          if at[(r + 1, c)] in rows and at[(r, c)] in rows]
    clipped = _clipped_copies(c_img, design)
    # Vignetting on the noise-free irradiance at λ_c, inside each copy's open code region.
    thr, fall = {}, {}
    for v in range(9):
        r0, c0, h, w = design.code_region_px(v)
        # Inset by a mask cell: the code region's edge cells may be closed (cells are kept when
        # their centre lies inside the region).
        k = int(math.ceil(design.mask_cell_px)) + 1
        win = _clip_window(design, r0 + k, c0 + k, h - 2 * k, w - 2 * k)
        if win is None or win[2] < 12 or win[3] < 12:
            continue
        a, b, hh, ww = win
        sub = c_img[a:a + hh, b:b + ww].astype(np.float64)
        # Only cells the code leaves open carry light; the field stop can close cells at edges.
        lit = sub[sub > 0]
        if lit.size == 0:
            continue
        med = float(np.median(lit))
        thr[v] = float(lit.mean())
        k = 4
        strips = [sub[:k], sub[-k:], sub[:, :k], sub[:, -k:]]
        fall[v] = float(1.0 - min(float(s.mean()) for s in strips) / med)
    ref = thr.get(0, float("nan"))
    return {
        "gap_x_px": float(min(gx)) if gx else float("nan"),
        "gap_y_px": float(min(gy)) if gy else float("nan"),
        "clipped_views": clipped,
        "throughput_rel": {str(v): t / ref for v, t in thr.items()},
        "edge_falloff": {str(v): f for v, f in fall.items()},
    }


def measure_all(design, *, spp: int = 8, seed: int = 0, dispersion_wavelengths=None) -> dict:
    """:func:`measure_geometry`, :func:`measure_dispersion` and :func:`measure_white` together,
    with :func:`predicted` for comparison (JSON-ready)."""
    return {
        "predicted": predicted(design),
        "geometry": measure_geometry(design, spp=spp, seed=seed),
        "dispersion": measure_dispersion(design, dispersion_wavelengths, spp=spp, seed=seed),
        "white": measure_white(design, spp=max(1, spp // 2), seed=seed),
    }
