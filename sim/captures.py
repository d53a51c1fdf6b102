r"""The calibration captures of a design, rendered as a lab would take them (paper Sec. 4.1–4.2).

Each capture is a raw frame (DN, float32) plus a JSON-ready sidecar (the one
:func:`sim.frame.simulate_frame` writes: ``design_hash``, ``monochromatic_nm``, ``exposure_ms``,
``radiance_scale``, ...) extended with ``target`` (what was in front of the instrument),
``repeats`` and, for the checkerboard and the ColorChecker, the target's geometry a lab knows
from the target's datasheet (``pattern_size``, the inner corners, and ``squares``, sized to the
views by :func:`checker_layout`; the patch reference radiances).  The reconstruction side reads
the board's pattern size from that sidecar, never from the design.

=================  ======================================================================
``white``          uniform white through every band's band-pass (L frames): the band's
                   whole wavelength interval, as a scene frame integrates it
``line``           a 1-px bright vertical line, monochromatic at every band centre (L frames)
``checker``        a checkerboard at 550 nm (``CHECKER_NM``), with a quiet white margin, its
                   squares sized to the view (:func:`checker_layout`)
``checker_white``  the uniform white at 550 nm (the checkerboard's flat field)
``colorchecker``   the 24-patch ColorChecker under D65, full spectrum (box band sampling, like
                   a scene frame), with the patches' reference radiances
``noise_frames``   the ColorChecker capture's single repeats, kept apart in pairs (every
                   pair the repeats make: 4 frames, 2 pairs, at the default; the sensor's
                   photon-transfer pairs, :mod:`recon.calibration.noise`; absent with fewer
                   than 2 repeats)
``comb``           optional (:func:`comb_captures`): a lattice of single lit texels through
                   every band's band-pass, all :math:`P_y P_x` phases (L·P_y·P_x frames,
                   streamed one at a time)
=================  ======================================================================

Noise.  Captures are taken with the sensor's shot and read noise and, as in a lab, ``repeats``
frames of each are averaged (the mean of N frames: noise / √N).  The optics are integrated
once per capture and only the sensor's noise is drawn per repeat, so the default of 4 repeats
costs milliseconds.  ``repeats=0`` renders noise-free frames instead (exact expectation,
quantised).

Independence.  Every capture goes through the transport traced with the captures' own seed
(:data:`sim.transport.exact.SEEDS`); scene frames and the exact operator use others.  The targets are
on the centre view's grid, the reconstruction grid of the calibrated models.

Exposure.  Every capture is auto-exposed (brightest pixel at 80 % of the full well); the
``radiance_scale`` in its sidecar is the exposure factor (radiance units per cube unit), which
the calibration divides out so that all captures and scene frames share one radiometric scale.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from recon.errors import InputError

__all__ = ["CHECKER_NM", "Captures", "checker_layout", "checker_target",
           "render_captures", "capture", "comb_captures"]

#: Wavelength of the geometric (checkerboard) capture, nm.
CHECKER_NM = 550.0


#: Fewest mask cells along a checkerboard square's side: the calibration unmasks the board by
#: dividing by the white and filling the chrome cells by normalised convolution, so a corner is
#: located only if each square shows several open cells along its edges.
CHECKER_MIN_CELLS = 5
#: Most squares along a side (7 × 7 inner corners, the board of views of ≥ 120 px).
CHECKER_MAX_SQUARES = 8


def checker_layout(design) -> dict:
    r"""The checkerboard's geometry on the centre view's :math:`v \times v` grid.

    Square side :math:`s = \max(\lfloor v/12 \rfloor, \lceil 5\,c \rceil)` with :math:`c` the
    mask cell in pixels (``CHECKER_MIN_CELLS`` cells per side); a white quiet zone of
    :math:`q = \max(2, \lfloor s/2 \rfloor)` px (OpenCV finds a board only when it does not
    touch the image edge).  The board is centred on the grid and must lie, with its quiet zone,
    inside the columns *every* view codes: the centre codes :math:`[0, v - g)`, a mirrored view
    :math:`[g, v)` (:math:`g` the guard stripe), hence

    .. math:: n_x = \min(8, \lfloor (v - 2g - 2q)/s \rfloor), \qquad
              n_y = \min(8, \lfloor (v - 2q)/s \rfloor)

    squares along x and y (at least 4 each: OpenCV needs more than 2 inner corners per side;
    if :math:`n_x < 4`, because a wide guard stripe leaves few columns that every view codes,
    the squares shrink to the smallest side, :math:`\lceil 5c \rceil`).
    Views of ≥ 120 px get the 8 × 8-square board of side :math:`\lfloor v/12 \rfloor`; smaller
    views fewer, larger squares.

    Returns
    -------
    dict
        ``square_px``, ``squares`` (n_x, n_y), ``pattern_size`` (n_x − 1, n_y − 1) inner
        corners (OpenCV's ``patternSize``: per row, per column), ``origin_px`` (y0, x0) of the
        board on the grid.

    Raises
    ------
    InputError
        Views too small for a board of 4 × 4 squares.
    """
    v = int(design.view_size_px)
    g = int(design.guard_px)
    smin = max(int(math.ceil(CHECKER_MIN_CELLS * float(design.mask_cell_px) - 1e-9)), 4)
    # The preferred square; the smallest one when a wide guard stripe leaves too few columns.
    for s in (max(v // 12, smin), smin):
        q = max(2, s // 2)
        nx = min(CHECKER_MAX_SQUARES, (v - 2 * g - 2 * q) // s)
        ny = min(CHECKER_MAX_SQUARES, (v - 2 * q) // s)
        if nx >= 4 and ny >= 4:
            break
    else:
        raise InputError(f"views of {v} px with a {g} px guard stripe are too small for a "
                         f"checkerboard calibration: the {v - 2 * g} px of columns that every "
                         f"view codes and the {v} px of rows hold {max(nx, 0)}x{max(ny, 0)} "
                         f"squares of {s} px (>= {CHECKER_MIN_CELLS} mask cells), need 4x4")
    return {"square_px": int(s), "squares": (int(nx), int(ny)),
            "pattern_size": (int(nx) - 1, int(ny) - 1),
            "origin_px": (int((v - ny * s) // 2), int((v - nx * s) // 2))}


def checker_target(design, wavelengths=None):
    r"""The checkerboard cube on the centre view's grid and its inner-corner count.

    The board of :func:`checker_layout` (its squares sized to the view and the mask cell),
    surrounded by a white quiet zone, white 0.9, black 0.05; square (0, 0) is white.

    Returns
    -------
    cube : (v, v, L) float32
    pattern_size : (cols, rows)
        Inner corners per row and column (OpenCV's ``patternSize``).
    """
    from scenes.spectra import illuminant

    wl = design.wavelengths if wavelengths is None else np.asarray(wavelengths, np.float64)
    v = design.view_size_px
    lay = checker_layout(design)
    s = lay["square_px"]
    nx, ny = lay["squares"]
    y0, x0 = lay["origin_px"]
    refl = np.full((v, v), 0.9, dtype=np.float32)
    yy, xx = np.mgrid[0:ny * s, 0:nx * s]
    board = ((yy // s + xx // s) % 2 == 0)
    refl[y0:y0 + ny * s, x0:x0 + nx * s] = np.where(board, 0.9, 0.05)
    cube = refl[:, :, None] * illuminant("E", wl).astype(np.float32)[None, None, :]
    return np.ascontiguousarray(cube, dtype=np.float32), lay["pattern_size"]


@dataclass
class Captures:
    """Every calibration capture of one design (frames (…, Hs, Ws) float32 DN, sidecars)."""

    design_hash: str
    wavelengths: np.ndarray            # (L,) band centres of the white/line stacks
    white: np.ndarray                  # (L, Hs, Ws)
    line: np.ndarray                   # (L, Hs, Ws)
    checker: np.ndarray                # (Hs, Ws) at CHECKER_NM
    checker_white: np.ndarray          # (Hs, Ws) at CHECKER_NM
    colorchecker: np.ndarray           # (Hs, Ws) full spectrum
    pattern_size: tuple
    #: (24, L) reference radiance of every patch (reflectance × D65, cube units).
    patch_radiance: np.ndarray
    #: Patch boxes (24, 4) = y0, x0, h, w on the centre view's grid (the chart's layout).
    patch_boxes: np.ndarray
    meta: dict = field(default_factory=dict)   # name -> sidecar (white/line: list per band)
    #: (2k, Hs, Ws) single frames of the ColorChecker capture, pairs (0, 1), (2, 3), … for
    #: the photon-transfer curve; k = repeats // 2 (None with < 2 repeats).
    noise_frames: np.ndarray | None = None

    def names(self) -> list[str]:
        """Capture names recorded in the calibration file."""
        return [f"white-band@{w:g}nm" for w in self.wavelengths] + \
               [f"line@{w:g}nm" for w in self.wavelengths] + \
               [f"checker@{CHECKER_NM:g}nm", f"white@{CHECKER_NM:g}nm", "colorchecker"]


def capture(design, cube, wavelengths, *, wavelength_nm=None, repeats: int = 4, seed: int = 0,
            target: str = "", sampling: str = "box", singles=None):
    r"""One capture: the mean of ``repeats`` noisy frames (or one noise-free frame if 0).

    The optics and the exposure are deterministic: the expected frame is integrated once and
    only the sensor's noise is drawn per repeat.  The transport is the captures' own realisation
    (:data:`sim.transport.exact.SEEDS`), never the one scene frames are rendered with.

    Returns
    -------
    frame : (Hs, Ws) float32, DN
    meta : dict
        :func:`sim.frame.simulate_frame`'s sidecar plus ``target`` and ``repeats``.

    ``singles``, a (n, Hs, Ws) float32 array, receives the first ``n`` repeats as they were
    read out, before averaging (the photon-transfer pairs).
    """
    from recon.kernels import cores, each
    from sim.bands import check_cube
    from sim.frame import FrameModel, exposure, frame_metadata
    from sim.sensor import digitise
    from sim.transport.exact import SEEDS

    if repeats < 0:
        raise InputError(f"repeats must be >= 0, got {repeats}")
    cube, wl = check_cube(design, cube, wavelengths)
    model = FrameModel(design, wl, sampling=sampling, wavelength_nm=wavelength_nm,
                       trace_seed=SEEDS["captures"])
    ne = model.electrons(cube)
    scale = exposure(ne, design)
    ne *= np.float32(scale)
    if repeats == 0:
        frame = digitise(ne, design, seed=seed, noise=False)
    else:
        acc = np.zeros(ne.shape, np.float64)
        # Same exposure for every repeat (the lab does not re-expose between frames).  Each
        # repeat draws from its own seed, so they are read out in parallel (the draws and the
        # readout release the GIL), a pair at a time on two cores, and summed in their order.
        for r0 in range(0, repeats, max(1, cores())):
            group = range(r0, min(repeats, r0 + max(1, cores())))
            for r, one in zip(group, each(lambda r: digitise(ne, design, seed=seed + r,
                                                             noise=True), group)):
                if singles is not None and r < len(singles):
                    singles[r] = one
                acc += one
        frame = (acc / repeats).astype(np.float32)
    meta = frame_metadata(design, model.bands_nm, wavelength_nm=wavelength_nm, seed=seed,
                          method="transport", spp=None, trace_seed=model.trace_seed,
                          scene_shape=cube.shape[:2], sampling=sampling, diffraction=True,
                          noise=repeats > 0, radiance_scale=scale)
    meta = dict(meta, target=target, repeats=int(repeats))
    return frame, meta


def render_captures(design, *, repeats: int = 4, seed: int = 1000, progress: bool = False,
                    keep_transport: bool = True, on_line=None) -> Captures:
    """Render every calibration capture of ``design`` (see the module docstring).

    The targets are cubes on the centre view's grid (``view_size_px`` square).  ``seed`` seeds
    the sensor noise (each capture its own seeds).  The band-pass captures (whites, ColorChecker)
    come first; with ``keep_transport=False`` their transport is dropped from memory before the
    monochromatic ones (0.4 GB for the paper design, while the white and line stacks fill).

    ``on_line``, a callable ``on_line(l, frame, whites)``, receives each line capture (band
    ``l``) as it is read out, with the whole (L, Hs, Ws) white stack (rendered before the
    lines), instead of its being kept: ``Captures.line`` is then None, and the line stack
    (0.95 GB on the paper design) is never held.  The captures themselves are the same.
    """
    from scenes.calibration import line, white
    from scenes.colorchecker import colorchecker, patch_boxes

    wl = design.wavelengths
    v = design.view_size_px
    shape = (v, v)
    pattern = checker_layout(design)["pattern_size"]
    b = patch_boxes(shape)                         # row0, col0, row1, col1

    steps = [("white", l) for l in range(wl.size)] + [("line", l) for l in range(wl.size)] + \
            [("checker", None), ("checker_white", None), ("colorchecker", None)]
    # Each capture keeps the noise seed of its place in `steps`; the band-pass ones (one
    # transport for all) run first, so that transport can go before the monochromatic ones,
    # and the ColorChecker first among them: its every band lit makes the largest blur
    # buffers (0.4 GB more on `paper`), which then come and go before the white stack fills.
    band_pass = [i for i, (name, _) in enumerate(steps) if name == "colorchecker"] + \
        [i for i, (name, _) in enumerate(steps) if name == "white"]
    order = band_pass + [i for i in range(len(steps)) if i not in band_pass]
    # Each target cube (84 MB on `paper`) is made before its first capture and dropped after
    # its last, not all held through the captures (the same cubes).
    makers = {"white": lambda: white(shape, wl), "line": lambda: line(shape, wl, width=1),
              "checker": lambda: checker_target(design, wl)[0],
              "colorchecker": lambda: colorchecker(shape, wl, illuminant="D65"),
              "band": lambda: np.zeros_like(target("white")),
              "checker_white": lambda: white(shape, wl)}
    uses = {"white": ("white",), "line": ("line",), "checker": ("checker",),
            "colorchecker": ("colorchecker",), "band": ("white",),
            "checker_white": ("checker_white",)}
    last_use = {t: max(p for p, i in enumerate(order) if steps[i][0] in names)
                for t, names in uses.items()}
    made: dict = {}

    def target(t):
        if t not in made:
            made[t] = makers[t]()
        return made[t]

    bar = None
    if progress:
        from recon.progress import progress_bar

        bar = progress_bar(total=len(steps), desc="calibration captures", unit="capture")
    from sim.transport import exact as transport

    # The band stacks are filled in place: a list of frames and its np.stack would hold both
    # (1.9 GB more at the peak for the paper design's 26 whites and 26 lines).
    whites = lines = radiance = None
    meta: dict = {"white": [], "line": []}
    out = {}
    before = checker_known = transport.held()
    try:
        for pos, i in enumerate(order):
            name, l = steps[i]
            s = seed + 101 * i
            if not keep_transport and i == order[len(band_pass)]:
                transport.release(keys=transport.held() - before)
            known = transport.held()
            if name == "checker":
                checker_known = known
            if name == "white":
                # A band-pass white (the band's whole interval, like a lab's filter of the band's
                # width), not a line at the band centre: the mask image then carries the
                # dispersion smear inside the band exactly as a scene frame does (measured: +4 dB
                # for one view on the ColorChecker of the small design).
                # One target buffer for every band, its band lit in turn.
                band = target("band")
                band[:, :, l] = target("white")[:, :, l]
                f, m = capture(design, band, wl, repeats=repeats, seed=s, target="white")
                band[:, :, l] = 0.0
                del band
                m["band_nm"] = float(wl[l])
                if whites is None:
                    whites = np.empty((wl.size,) + f.shape, np.float32)
                whites[l] = f
                meta["white"].append(m)
            elif name == "line":
                f, m = capture(design, target("line"), wl, wavelength_nm=wl[l], repeats=repeats,
                               seed=s, target="line")
                m["column"] = v // 2       # the line's place on the target (its datasheet)
                meta["line"].append(m)
                if on_line is not None:
                    on_line(l, f, whites)
                else:
                    if lines is None:
                        lines = np.empty((wl.size,) + f.shape, np.float32)
                    lines[l] = f
            elif name == "checker":
                f, m = capture(design, target("checker"), wl, wavelength_nm=CHECKER_NM,
                               repeats=repeats, seed=s, target="checkerboard")
                # What a lab knows from its target's datasheet: the board's layout.
                lay = checker_layout(design)
                m["pattern_size"] = list(pattern)
                m["squares"] = list(lay["squares"])
                out["checker"], meta["checker"] = f, m
            elif name == "checker_white":
                f, m = capture(design, target("checker_white"), wl, wavelength_nm=CHECKER_NM,
                               repeats=repeats, seed=s, target="white")
                out["checker_white"], meta["checker_white"] = f, m
            else:
                sensor = (int(design.sensor_height_px), int(design.sensor_width_px))
                # Every pair the repeats make: two pairs halve the photon-transfer fit's
                # variance of one (its gain's spread 0.92 % → 0.64 % on `small`, 20 seeds).
                pairs = repeats // 2
                singles = np.empty((2 * pairs,) + sensor, np.float32) if pairs else None
                cc_cube = target("colorchecker")
                # The patches' reference radiance: the chart's value at each patch centre.
                radiance = np.stack([cc_cube[r0 + (r1 - r0) // 2, c0 + (c1 - c0) // 2]
                                     for r0, c0, r1, c1 in b]).astype(np.float64)
                f, m = capture(design, cc_cube, wl, repeats=repeats, seed=s,
                               target="colorchecker", singles=singles)
                del cc_cube
                out["colorchecker"], meta["colorchecker"] = f, m
                out["noise_frames"] = singles
            del f
            for t in [t for t in made if last_use[t] == pos]:
                del made[t]
            if name in ("line", "checker_white"):
                # A monochromatic capture's transport (one wavelength, its throughput images
                # computed) serves that capture only (the checkerboard's also its white's),
                # and the memo would hold all 27 to the end of the process.
                since = checker_known if name == "checker_white" else known
                transport.release(keys=transport.held() - since)
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()

    boxes = np.stack([b[:, 0], b[:, 1], b[:, 2] - b[:, 0], b[:, 3] - b[:, 1]], axis=1)
    return Captures(design_hash=design.hash, wavelengths=wl.copy(),
                    white=whites, line=lines, checker=out["checker"],
                    checker_white=out["checker_white"], colorchecker=out["colorchecker"],
                    pattern_size=tuple(pattern), patch_radiance=radiance,
                    patch_boxes=boxes.astype(np.int64), meta=meta,
                    noise_frames=out["noise_frames"])


def comb_captures(design, period, *, repeats: int = 4, seed: int = 5000,
                  progress: bool = False):
    """Band-pass captures of the comb targets (:func:`scenes.calibration.comb`), all phases.

    ``period`` (rows, columns) is the lab's choice, larger than a pixel's footprint
    (:func:`recon.calibration.footprint.comb_period`).

    A generator, so that only one frame is held at a time: it yields ``(band, (a, b), frame,
    meta)`` for every band ``l`` and phase ``(a, b)``, band-major.  The sidecar adds what a lab
    knows of its target: ``period``, ``phase``, ``grid`` (the target's texel rows and columns,
    the scenes' grid), ``band_nm`` and ``radiance`` (a lit texel's, cube units).
    """
    from scenes.calibration import comb, white

    wl = design.wavelengths
    v = design.view_size_px
    py, px = (int(p) for p in period)
    level = white((v, v), wl)[0, 0]
    bar = None
    if progress:
        from recon.progress import progress_bar

        bar = progress_bar(total=wl.size * py * px, desc="comb captures", unit="capture")
    try:
        for l in range(wl.size):
            for a in range(py):
                for b in range(px):
                    cube = np.zeros((v, v, wl.size), np.float32)
                    cube[:, :, l] = comb((v, v), wl, period=(py, px), phase=(a, b))[:, :, l]
                    f, m = capture(design, cube, wl, repeats=repeats,
                                   seed=seed + 7919 * l + 31 * (a * px + b), target="comb")
                    m.update(period=[py, px], phase=[a, b], grid=[v, v], band_nm=float(wl[l]),
                             radiance=float(level[l]))
                    yield l, (a, b), f, m
                    if bar is not None:
                        bar.update(1)
    finally:
        if bar is not None:
            bar.close()
