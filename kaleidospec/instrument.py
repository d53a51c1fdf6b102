r"""The simulated instrument, as the application sees it: designs, raw frames, calibration
captures and the design's exact operator.

This is the only module of :mod:`kaleidospec` that imports :mod:`sim`; the other stages see
what a lab sees — a design description, raw frames with their sidecars, captures of known
targets — and so would work unchanged on a real instrument.  The built-in scenes are rendered
here too (:mod:`scenes`).

- **Designs** (:mod:`sim.optics.design`): :func:`get_design`, :func:`parse_overrides`,
  :func:`design_for_views` (a design that traces the views a count needs) and
  :func:`design_of` (the design a frame's sidecar records).
- **Frames**: :func:`render_scene` (one scene, its raw frame and its ground truth),
  :func:`grid_on_scene` and :func:`view_answers` (where a calibration's grid lies on the scene,
  for the truth, and how far its views agree on that),
  :func:`scene_cube`, :func:`simulate_frame` and :func:`write_frame` (the steps of
  ``kaleidospec render``), :class:`FrameRenderer` (many frames of one design: a video) and
  :func:`animation` (a moving scene).
- **Calibration captures** (:mod:`sim.captures`): :func:`render_captures` (whites, lines,
  checkerboard and ColorChecker), :func:`comb_captures` (the footprint model's comb targets),
  the band-pass filters :func:`band_intervals` and the design's dispersion averaged over each
  band, :func:`band_mean_dispersion`.
- **The exact operator** (:mod:`sim.transport.oracle`): :func:`oracle_operator` and
  :func:`oracle_measurements`, the converged optics the calibrated models are measured against.
- **Design studies** (:mod:`sim.measure`, :mod:`sim.optics.glass`): :func:`measure_design`,
  :func:`apex_for_span`.
- **Housekeeping**: :func:`cache_dir` (where transports and calibrations are cached),
  :func:`limit_threads`, :func:`release_transports`.

Independence of frames and captures.  A scene frame is built at
:data:`sim.frame.SCENE_OVERSAMPLE` times the reconstruction grid (a cube file keeps its own
resolution), so it carries detail no reconstruction grid holds, and it goes through the
transport traced with the scene frames' own seed (:data:`sim.transport.exact.SEEDS`), another
realisation of the optics than the captures'.  A calibration learnt from the captures is
therefore scored on light it has not seen.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from recon.errors import InputError
from recon.view_ids import VIEW_ORDER
from sim.bands import band_intervals
from sim.captures import CHECKER_NM, comb_captures, render_captures
from sim.optics.design import Design, get_design, parse_overrides
from sim.frame import ground_truth, simulate_frame, write_frame
from sim.optics.glass import apex_for_span
from sim.measure import measure_all as measure_design
from sim.transport.oracle import oracle_measurements, oracle_operator

__all__ = [
    "Design", "get_design", "parse_overrides", "design_for_views", "design_of",
    "render_scene", "scene_cube", "grid_on_scene", "view_answers", "simulate_frame",
    "write_frame", "ground_truth", "FrameRenderer", "animation", "render_captures",
    "comb_captures", "noise_free_whites", "CHECKER_NM",
    "band_intervals", "band_mean_dispersion", "oracle_operator", "oracle_measurements",
    "measure_design", "apex_for_span", "cache_dir", "limit_threads", "release_transports",
]


# ------------------------------------------------------------------------------- designs
def design_for_views(design, n_views: int):
    """``design`` with its ``views`` widened to hold the first ``n_views`` views.

    The ``views`` field only says which views the simulator traces and calibration finds (the
    optics are the same), so a 9-view run uses the same design with all nine views; its hash,
    and so its caches, differ.
    """
    need = VIEW_ORDER[:int(n_views)]
    if set(need) <= set(design.views):
        return design
    return design.replace(views=tuple(sorted(set(design.views) | set(need))))


def design_of(metadata, design=None):
    """``design`` if given, else the design recorded in a raw frame's sidecar."""
    if design is not None:
        return design
    d = (metadata or {}).get("design")
    if not isinstance(d, dict):
        raise InputError("the frame's sidecar has no design: cannot place the ground truth")
    return Design.from_dict(d)


# ------------------------------------------------------------------------------- frames
def scene_cube(scene, design, **scene_params):
    """The cube ``(H, W, L)`` and wavelengths of a built-in scene or a cube file, at the
    design's bands: a built-in scene on :func:`sim.frame.scene_grid` (finer than any
    reconstruction grid), a file at its own resolution."""
    from scenes.registry import get_scene
    from sim.frame import scene_grid

    return get_scene(str(scene), shape=scene_grid(design, scene),
                     wavelengths=design.wavelengths, **scene_params)


def render_scene(scene, design, *, seed: int = 0, noise: bool = True, angle_deg=None,
                 radiance_scale=None, native: bool = False, **scene_params):
    """Render the raw frame of a built-in scene or a cube file.

    Parameters
    ----------
    scene : str or path
        A name from :func:`scenes.registry.list_scenes` or a cube file.
    design : sim.optics.design.Design
    seed : int
        Sensor noise seed.
    noise : bool
        Shot and read noise.
    angle_deg : float, optional
        Rotation of the colour wheel (``colorwheel`` only; a scene parameter).
    radiance_scale : float, optional
        Fixed exposure (default: auto-exposure, brightest pixel at 80 % of the full well).
    native : bool
        Return the scene itself (its own resolution) as the truth, for
        :func:`kaleidospec.models.truth_on_grid` (exact on a calibrated model's grid) and
        :func:`sim.frame.ground_truth` (the design's grid).
    **scene_params
        Passed to the scene builder.

    Returns
    -------
    frame : (Hs, Ws) float32, DN
    metadata : dict
        The sidecar (``design_hash``, ``radiance_scale``, ``scene``, ...).
    truth : (v, v, L) float32
        The scene averaged onto the centre view's grid (:func:`sim.frame.ground_truth`), or
        with ``native`` the scene cube (H, W, L) itself; see
        :func:`kaleidospec.models.truth_on_grid` for a model's reconstruction grid.
    wavelengths : (L,) float64
    """
    if angle_deg is not None:
        scene_params["angle_deg"] = angle_deg
    cube, wl = scene_cube(scene, design, **scene_params)
    frame, meta = simulate_frame(design, cube, wl, seed=seed, noise=noise,
                                 radiance_scale=radiance_scale)
    meta["scene"] = str(scene)
    if scene_params:
        meta["scene_params"] = {k: v_ for k, v_ in scene_params.items()}
    truth = np.asarray(cube, np.float32) if native else ground_truth(design, cube)
    return frame, meta, truth, wl


class FrameRenderer:
    r"""Raw frames of one design from its transport: :class:`sim.frame.FrameModel` (the exact
    pixel integrals, each band's Airy blur and the sensor's photo-electrons) and a noise draw.

    The mean photo-electron count of a pixel is :math:`s\,\bar N_e` with :math:`s` the
    radiance scale (exposure); the frame is :func:`sim.sensor.digitise` of it.  The transport
    is the scene frames' (:data:`sim.transport.exact.SEEDS`), loaded once; this matches
    :func:`sim.frame.simulate_frame` (the tests check it).

    Parameters
    ----------
    design : sim.optics.design.Design
    shape : (H, W)
        The scene cubes' grid (any resolution).
    wavelengths : array (L,), optional
        Bands of the design (all by default).
    sampling : {"box", "centre"}
    diffraction : bool
        Airy blur per band.
    progress : bool
        Progress bar while the transport is traced (first use of a design only).
    """

    def __init__(self, design, shape, wavelengths=None, *, sampling: str = "box",
                 diffraction: bool = True, progress: bool = False):
        from sim.bands import check_cube
        from sim.frame import FrameModel
        from sim.transport.exact import SEEDS

        wl = design.wavelengths if wavelengths is None else wavelengths
        h, w = (int(s) for s in shape)
        _, wl = check_cube(design, np.zeros((1, 1, np.size(wl)), np.float32), wl)
        self.design, self.shape, self.wavelengths = design, (h, w), wl
        self.sampling, self.diffraction = sampling, bool(diffraction)
        self.model = FrameModel(design, wl, sampling=sampling, trace_seed=SEEDS["scene"],
                                diffraction=diffraction, progress=progress)

    def electrons(self, cube) -> np.ndarray:
        """Mean photo-electrons (Hs, Ws) float32 for a radiance scale of 1."""
        cube = np.asarray(cube, np.float32)
        if cube.shape[:2] != self.shape:
            raise InputError(f"cube shape {cube.shape[:2]} differs from the renderer's {self.shape}")
        return self.model.electrons(cube)

    def exposure_for(self, cube, auto_exposure: float = 0.8, *, electrons=None) -> float:
        """The radiance scale that puts the brightest pixel of ``cube`` at ``auto_exposure`` of
        the full well (:func:`sim.frame.simulate_frame`'s rule); ``electrons``, the cube's
        :meth:`electrons` when the caller has them already."""
        from sim.frame import exposure

        ne = self.electrons(cube) if electrons is None else electrons
        return exposure(ne, self.design, auto_exposure)

    def render(self, cube, *, radiance_scale: float, seed=0, noise: bool = True,
               electrons=None) -> np.ndarray:
        """Raw frame (Hs, Ws) float32 in DN; ``seed`` (int or sequence) seeds the noise.

        ``electrons``, :meth:`electrons` of ``cube`` when the caller has them already (the
        exposure of a video's first frame is taken from them), is scaled in place and used
        instead of computing them again: the same frame."""
        from sim.sensor import digitise

        ne = self.electrons(cube) if electrons is None else electrons
        ne *= np.float32(radiance_scale)
        return digitise(ne, self.design, rng=np.random.default_rng(seed), noise=noise)

    def metadata(self, *, radiance_scale: float, seed: int, noise: bool) -> dict:
        """The sidecar of :func:`sim.frame.simulate_frame` for these settings."""
        from sim.frame import frame_metadata

        return frame_metadata(self.design, self.wavelengths, wavelength_nm=None, seed=seed,
                              method="transport", spp=None, trace_seed=self.model.trace_seed,
                              scene_shape=self.shape, sampling=self.sampling,
                              diffraction=self.diffraction, noise=noise,
                              radiance_scale=radiance_scale)


def noise_free_whites(design, view_boxes) -> np.ndarray:
    """Every band's band-pass white rendered without noise and without the Airy blur through
    the calibration captures' trace (:data:`sim.transport.exact.SEEDS`), cropped to
    ``view_boxes`` (K, 4): (K, L, Hv, Wm) float32 photo-electrons.  What a perfect
    deconvolution of noise-free white captures would give: the simulator's own mask images,
    once normalised (:func:`recon.calibration.mask.normalise_mask_images`)."""
    from recon.calibration.mask import view_stack
    from scenes.calibration import white
    from sim.frame import FrameModel
    from sim.transport.exact import SEEDS

    wl = design.wavelengths
    cube = white((design.view_size_px,) * 2, wl)
    model = FrameModel(design, wl, trace_seed=SEEDS["captures"], diffraction=False)
    boxes = np.asarray(view_boxes)
    out = np.empty((len(boxes), wl.size, int(boxes[0, 2]), int(boxes[0, 3])), np.float32)
    band = np.zeros_like(cube)
    for l in range(wl.size):
        band[:, :, l] = cube[:, :, l]
        out[:, l] = view_stack(model.electrons(band)[None], boxes)[:, 0]
        band[:, :, l] = 0.0
    return out


def animation(scene, design, *, n_frames=None, fps: float = 10.0, subframes: int = 1,
              **scene_params):
    """A moving scene (:func:`scenes.animated.get_animation`: ``colorwheel``,
    ``moving_object`` or a folder of cubes) on the design's scene grid and bands, each frame
    integrated over the design's exposure."""
    from scenes.animated import get_animation
    from sim.frame import scene_grid

    return get_animation(scene, scene_grid(design), design.wavelengths, n_frames=n_frames,
                         fps=fps, exposure_ms=design.exposure_ms, subframes=subframes,
                         **scene_params)


# ------------------------------------------------------------------------------- ground truth
#: Grid corners between which :func:`grid_on_scene` evaluates the optics exactly (a bicubic
#: spline fills in the rest: the maps are low-order polynomials, so it is exact to < 10⁻⁴ px).
GRID_MAP_STEP = 16


def grid_on_scene(design, cal, view_ids=None) -> tuple[np.ndarray, np.ndarray]:
    r"""Where the corners of a calibration's grid lie on the scene: ``(x, y)``, each
    (H + 1, W + 1) float64, in the design grid's pixels (the scene spans :math:`[0, v]^2`, pixel
    edges at integers), for the grid (H, W) of the shifted and smeared models.

    Every calibrated view :math:`k` says where grid point :math:`g` is: at view pixel
    :math:`q = H_k g + d_k(H_k g)` (its homography and displacement field), which band
    :math:`l` puts on box column :math:`q_x + o_{k,l}` (the band's offset).  The scene point that
    sensor point shows in band :math:`l` is read off the simulator's exact maps (the scene
    frames' transport, :mod:`sim.transport.maps`: mask-plane position averaged over the band's nodes, then
    the relay to the diffuser); the view's answer is its mean over the bands, and the grid point
    is the mean of the answers of ``view_ids`` (default: every calibrated view), the views a
    reconstruction uses.  Where the views disagree (a calibration error) no registration
    satisfies all of them and the reconstruction pays for it; a global placement the views agree
    on is not an error of the instrument.

    The design grid translated by the design's mean dispersion
    (:func:`kaleidospec.models.grid_offset`) is where this grid would be if the lenses did not
    distort and the prism had no anamorphic scale: on `paper` the centre view's answer parts
    from it by up to 1.1 px at the view's edges.
    """
    from scipy.interpolate import RectBivariateSpline

    (gy, gx), answers = view_answers(design, cal, view_ids)
    x = np.mean([a[0] for a in answers.values()], axis=0)
    y = np.mean([a[1] for a in answers.values()], axis=0)
    h, w = (int(n) for n in cal.cube_shape[:2])
    ry, rx = np.arange(h + 1, dtype=np.float64), np.arange(w + 1, dtype=np.float64)
    deg = {"kx": min(3, gy.size - 1), "ky": min(3, gx.size - 1)}    # a spline needs deg + 1 nodes
    return (RectBivariateSpline(gy, gx, x, **deg)(ry, rx),
            RectBivariateSpline(gy, gx, y, **deg)(ry, rx))


def view_answers(design, cal, view_ids=None, step: int = GRID_MAP_STEP):
    """Where each of the views ``view_ids`` (default: all the calibration's) puts the grid's
    corners on the scene (:func:`grid_on_scene`), every ``step`` corners along each axis.

    Returns
    -------
    (gy, gx) : 1-D float64 arrays
        The grid-corner rows and columns evaluated (edge coordinates, the last corner included).
    answers : dict
        ``{view id: (x, y)}``, each (gy.size, gx.size) float64 in the design grid's pixels.
        Where the views' answers differ, the calibration disagrees with itself.
    """
    from sim.transport.exact import SEEDS, load_or_build

    idx = cal.view_indices(view_ids)
    tr = load_or_build(design, design.wavelengths, seed=SEEDS["scene"])
    if tr.n_bands != cal.n_bands:
        raise InputError(f"the design has {tr.n_bands} bands, the calibration {cal.n_bands}")
    h, w = (int(n) for n in cal.cube_shape[:2])
    gy = np.unique(np.r_[np.arange(0, h + 1, int(step)), h]).astype(np.float64)
    gx = np.unique(np.r_[np.arange(0, w + 1, int(step)), w]).astype(np.float64)
    ex, ey = np.meshgrid(gx, gy)
    v = float(design.view_size_px)
    answers = {}
    for i in idx:
        vx, vy = _view_answer(tr, cal, i, ex, ey)
        answers[cal.view_ids[i]] = (vx * v, vy * v)
    return (gy, gx), answers


def _view_answer(tr, cal, i, ex, ey):
    """Where calibration view index ``i`` puts grid edge points ``(ex, ey)`` on the scene,
    averaged over the bands: (x, y) in units of the scene's side (:func:`grid_on_scene`)."""
    from sim.transport.maps import legendre_values
    from sim.transport.pixel_integral import band_mean

    maps, k = tr.maps, tr.views.index(int(cal.view_ids[i]))
    # Grid and view coordinates put pixel centres at integers, edges at half-integers.  A view's
    # lead (recon.calibration.extent) moves its image and its offsets alike: it cancels here.
    p = np.tensordot(np.asarray(cal.homographies[i], np.float64),
                     np.stack([ex - 0.5, ey - 0.5, np.ones_like(ex)]), 1)
    qx, qy = p[0] / p[2], p[1] / p[2]
    field = cal.field(i)
    if field is not None:
        dx, dy = field(qx, qy)
        qx, qy = qx + dx, qy + dy
    rc, sr, cc, sc = maps.norm[k]
    ax, bx, ay, by = (float(a) for a in maps.relay[k])
    box_y, box_x = (float(a) for a in cal.view_boxes[i, :2])
    pr = legendre_values(((box_y + qy + 0.5 - rc) / sr).ravel(), maps.degree)
    x = np.zeros(qx.size)
    y = np.zeros(qx.size)
    for l in range(cal.n_bands):
        cx = band_mean(maps.mask[k, :, 0], tr.band_nodes[l])
        cy = band_mean(maps.mask[k, :, 1], tr.band_nodes[l])
        pc = legendre_values(((box_x + qx + float(cal.offsets[i, l]) + 0.5 - cc) / sc).ravel(),
                             maps.degree)
        x += ax + bx * np.einsum("na,ab,nb->n", pr, cx, pc)
        y += ay + by * np.einsum("na,ab,nb->n", pr, cy, pc)
    return (x / cal.n_bands).reshape(qx.shape), (y / cal.n_bands).reshape(qx.shape)


# ------------------------------------------------------------------------------- bands
def band_mean_dispersion(design, wavelengths, samples: int = 32) -> np.ndarray:
    r"""(L,) the design's dispersion :math:`\varphi` averaged over every band's interval (px),
    at ``samples`` wavelengths a band: the counterpart of
    :func:`recon.calibration.band_mean_positions`."""
    from recon.calibration.dispersion import band_wavelengths

    lam = band_wavelengths(band_intervals(design, np.asarray(wavelengths, dtype=np.float64)),
                           samples)
    return design.dispersion_px_at(lam.ravel()).reshape(lam.shape).mean(axis=1)


# ------------------------------------------------------------------------------- housekeeping
def cache_dir(folder=None) -> Path:
    """``folder`` (created if missing), else the simulator's cache folder
    (``$KALEIDOSPEC_CACHE`` or ``~/.cache/kaleidospec``): transports and calibrations."""
    if folder is not None:
        from recon.io.cache import check_folder

        return check_folder(folder)     # one line (exit 2) when it cannot be written
    from sim.transport.exact import cache_dir as default

    return default()


def limit_threads(threads: int | None) -> None:
    """Limit drjit's threads (a worker process of a parallel sweep must not oversubscribe the
    cores); ``None`` or 0 leaves them."""
    if threads:
        import drjit as dr

        from sim.optics.variant import ensure_variant

        ensure_variant()
        dr.set_thread_count(int(threads))


def release_transports(which: str | None = None) -> None:
    """Drop the transports held in memory: each design point of a sweep has its own.

    ``which`` (a key of :data:`sim.transport.exact.SEEDS`) drops only that realisation's: the
    captures' once a calibration has them (0.4 GB for the paper design)."""
    from sim.transport import exact as transport

    transport.release(None if which is None else transport.SEEDS[which])
