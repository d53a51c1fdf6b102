r"""Hyperspectral video (x, y, λ, t): dynamic scenes rendered and reconstructed frame by frame.

Rendering.  The optics are linear and static, so a sequence reuses the design's transport
(:mod:`sim.transport`): :class:`FrameRenderer` loads it once and each frame is only its pixel
integrals, the sensor's per-band QE, band width and Airy blur, and the shot/read noise draw.  Every frame
of a sequence shares one exposure (``radiance_scale``, fixed from frame 0 unless given), as a
video camera at a fixed shutter and gain would, so brightness does not flicker.

Reconstruction.  Consecutive frames differ little, so frame :math:`t` starts from the
reconstruction of frame :math:`t-1` (a warm start) and needs fewer iterations (``iters``) than a
cold start (``cold_iters``, from :math:`H^\top\Phi^{-1}g`).  Optionally a temporal TV term
:math:`\mu\lVert f_t - \hat f_{t-1}\rVert_1` ties a frame to the previous reconstruction
(:mod:`recon.temporal`).  Warm starts chain frames only within a *segment*; segments are
independent, so a long sequence is split into segments that run in parallel: in local
processes (all cores by default) or, given a scheduler address, on a Dask cluster whose
workers see the same output folder (``dask.distributed`` is imported only then).  The operator
(and GAP-TV's step) is built once per segment, not per frame.

Resume.  Every file is written atomically (temporary file + rename) and each frame's last file
is its marker: a raw frame is done when its sidecar exists (written after the image), a
reconstructed frame when its metrics file exists (written after the cube).  A new run on the same
folder skips finished frames; an interrupted frame is redone from the start; a warm start after
an interruption reads the previous frame's cube back (float32 EXR, lossless, so the result is
the same as without the interruption).  ``video.json`` pins the settings: a run with other
settings on the same folder is refused.

Layout of the output folder::

    video.json                 settings, exposure, segments (the resume contract)
    raw/frame_00000.exr|.json  raw frames + sidecars
    truth/frame_00000.exr      ground truth on the reconstruction grid (spectral EXR)
    cubes/frame_00000.exr      reconstructions (spectral EXR, recon.io.cubes.write_cube)
    metrics/frame_00000.json   per-frame metrics (the frame's done marker)
    metrics.json, metrics.csv  all frames' metrics and their summary
    video.gif (or .webp)       sRGB: ground truth | reconstruction, side by side
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import time
from pathlib import Path

import numpy as np

from recon.errors import InputError
from recon.io.arrays import read_json_object

__all__ = [
    "FrameRenderer", "VideoLayout", "render_sequence", "plan_segments", "reconstruct_segment",
    "reconstruct_sequence", "sector_colour_errors", "write_summary", "write_video",
    "run_video", "SegmentReconstructor",
]

# ---------------------------------------------------------------------------------------------
# files
# ---------------------------------------------------------------------------------------------
class VideoLayout:
    """Paths of a video output folder (see the module notes)."""

    def __init__(self, root):
        self.root = Path(root)
        self.raw_dir = self.root / "raw"
        self.truth_dir = self.root / "truth"
        self.cube_dir = self.root / "cubes"
        self.metrics_dir = self.root / "metrics"
        self.manifest = self.root / "video.json"

    @staticmethod
    def name(i: int) -> str:
        return f"frame_{int(i):05d}"

    def raw(self, i: int) -> Path:
        return self.raw_dir / f"{self.name(i)}.exr"

    def raw_sidecar(self, i: int) -> Path:
        return self.raw_dir / f"{self.name(i)}.json"

    def truth(self, i: int) -> Path:
        return self.truth_dir / f"{self.name(i)}.exr"

    def cube(self, i: int) -> Path:
        return self.cube_dir / f"{self.name(i)}.exr"

    def metrics(self, i: int) -> Path:
        return self.metrics_dir / f"{self.name(i)}.json"

    def make(self) -> None:
        for d in (self.root, self.raw_dir, self.truth_dir, self.cube_dir, self.metrics_dir):
            d.mkdir(parents=True, exist_ok=True)

    def rendered(self, i: int) -> bool:
        """Raw frame, sidecar and truth all present (the sidecar is written last)."""
        return self.raw_sidecar(i).exists() and self.raw(i).exists() and self.truth(i).exists()

    def reconstructed(self, i: int) -> bool:
        """Cube and metrics present (the metrics file is written last)."""
        return self.metrics(i).exists() and self.cube(i).exists()

    def count_reconstructed(self, n: int) -> int:
        return sum(self.reconstructed(i) for i in range(n))


def _write_json(path: Path, obj) -> None:
    from recon.io.atomic import write_text

    write_text(path, json.dumps(obj, indent=2, sort_keys=True, allow_nan=False) + "\n")



# ---------------------------------------------------------------------------------------------
# rendering
# ---------------------------------------------------------------------------------------------
class FrameRenderer:
    r"""Raw frames of one design from its transport: :class:`sim.frame.FrameModel` (the exact
    pixel integrals, each band's Airy blur and the sensor's photo-electrons) and a noise draw.

    The mean photo-electron count of a pixel is :math:`s\,\bar N_e` with :math:`s` the
    radiance scale (exposure); the frame is :func:`sim.sensor.digitise` of it.  The transport
    is the scene frames' (:data:`sim.transport.SEEDS`), loaded once; this matches
    :func:`sim.frame.simulate_frame` (the tests check it).

    Parameters
    ----------
    design : sim.design.Design
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
        from sim.transport import SEEDS

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

    def exposure_for(self, cube, auto_exposure: float = 0.8) -> float:
        """The radiance scale that puts the brightest pixel of ``cube`` at ``auto_exposure`` of
        the full well (:func:`sim.frame.simulate_frame`'s rule)."""
        from sim.frame import exposure

        return exposure(self.electrons(cube), self.design, auto_exposure)

    def render(self, cube, *, radiance_scale: float, seed=0, noise: bool = True) -> np.ndarray:
        """Raw frame (Hs, Ws) float32 in DN; ``seed`` (int or sequence) seeds the noise."""
        from sim.sensor import digitise

        ne = self.electrons(cube)
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


def render_sequence(anim, design, out_dir, *, radiance_scale: float, seed: int = 0,
                    noise: bool = True, renderer: FrameRenderer | None = None,
                    progress: bool = True, scene: str = "") -> dict:
    """Render every frame of ``anim`` not rendered yet into ``out_dir`` (see the layout).

    Frame *i* gets the noise seed ``[seed, i]``; its sidecar records ``frame``, ``time_s``
    (shutter opening) and the scene.  The ground truth (the cube on the centre view's grid,
    :func:`sim.frame.ground_truth`) is written first, then the raw image, then its sidecar.

    Returns
    -------
    dict
        ``rendered`` and ``skipped`` frame counts, ``seconds`` (rendering only, writes
        excluded) and ``write_seconds``.
    """
    from recon.io.cubes import write_cube
    from recon.io.raw import write_raw
    from sim.frame import ground_truth

    lay = VideoLayout(out_dir)
    lay.make()
    todo = [i for i in range(len(anim)) if not lay.rendered(i)]
    stats = {"rendered": 0, "skipped": len(anim) - len(todo), "seconds": 0.0,
             "write_seconds": 0.0, "scene_seconds": 0.0}
    if not todo:
        return stats
    if renderer is None:
        renderer = FrameRenderer(design, anim.shape, anim.wavelengths, progress=progress)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(anim), initial=stats["skipped"], desc="render", unit="frame")
    desc = anim.describe()
    try:
        for i in todo:
            t0 = time.perf_counter()
            cube = anim.frame(i)
            t1 = time.perf_counter()
            frame = renderer.render(cube, radiance_scale=radiance_scale, seed=[int(seed), i],
                                    noise=noise)
            t2 = time.perf_counter()
            meta = renderer.metadata(radiance_scale=radiance_scale, seed=seed, noise=noise)
            meta.update(frame=i, time_s=anim.start_s(i), fps=anim.fps, scene=scene,
                        animation=desc, noise_seed=[int(seed), i])
            write_cube(lay.truth(i), ground_truth(design, cube), anim.wavelengths)
            write_raw(lay.raw(i), frame, meta)
            stats["scene_seconds"] += t1 - t0
            stats["seconds"] += t2 - t0
            stats["write_seconds"] += time.perf_counter() - t2
            stats["rendered"] += 1
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    return stats


# ---------------------------------------------------------------------------------------------
# reconstruction of one frame and of a segment
# ---------------------------------------------------------------------------------------------
class SegmentReconstructor:
    r"""One frame's inverse problem, set up once per segment and reused for every frame.

    Two kinds (constructors):

    - :meth:`calibrated` — what the instrument does: the problem of
      :func:`kaleidospec.pipeline.reconstruct_views` (operator
      :func:`kaleidospec.pipeline.calibrated_operator`, gains folded in; the measurement over
      the frame's ``radiance_scale``), on the calibration's grid;
    - :meth:`oracle` — the exact operator of the design
      (:func:`kaleidospec.pipeline.oracle_operator`) on the ground-truth grid, to separate the
      engine's behaviour from calibration errors.

    Either way the operator and GAP-TV's step :math:`1/\lVert\Phi^{-1/2}H\rVert^2` are
    computed once, not per frame.

    Parameters
    ----------
    op : LinearOperator
        ``(L, H, W) -> (K, Hv, Wm)``.
    measure : callable
        ``measure(frame, metadata) -> g`` (K, Hv, Wm) float32.
    solver : str
        A :mod:`recon.solvers` name.
    tau : float, optional
        TV weight (the solver's default if None).
    threads : int, optional
        Threads of the TV prox (GAP-TV and the temporal variant).
    to_grid : callable, optional
        ``to_grid(truth (v, v, L), metadata) -> truth on the operator's grid``.
    offset : callable, optional
        ``offset(metadata) -> (oy, ox)``: where the operator's grid sits on the truth's.
    """

    def __init__(self, op, measure, *, solver: str = "gap-tv", tau: float | None = None,
                 threads: int | None = None, to_grid=None, offset=None, kind: str = ""):
        from kaleidospec.pipeline import tv_weight, unit_row_scale
        from recon.operators import ScaledOperator

        # The pipeline's scaling and TV weight, so that a video frame is reconstructed exactly
        # as `kaleidospec run` reconstructs a still (kaleidospec.pipeline.solve_views).
        scale = unit_row_scale(op)
        self.op = ScaledOperator(op, scale)
        self._measure = lambda frame, meta: measure(frame, meta) * np.float32(scale)
        self.solver = solver
        self.tau = tv_weight(solver, tau, op.oshape[0])
        self.threads = threads
        self._to_grid = to_grid
        self._offset = offset
        self.kind = kind
        self._step = None

    @classmethod
    def calibrated(cls, cal, n_views: int, **kw) -> "SegmentReconstructor":
        """From a calibration: the first ``n_views`` views (centre, left, right, top, ...)."""
        from kaleidospec.pipeline import (_check_views, _design_of, calibrated_operator,
                                          grid_offset, truth_on_grid)

        ids = _check_views(n_views)
        missing = [v for v in ids if v not in cal.view_ids]
        if missing:
            raise InputError(f"view(s) {missing} missing: the calibration has views "
                             f"{list(cal.view_ids)}")
        # Gains folded into the masks: the cube comes out in the scene's radiance units.
        op = calibrated_operator(cal, ids)
        return cls(op, lambda frame, meta: _frame_measurement(frame, meta, cal, ids),
                   to_grid=lambda t, meta: truth_on_grid(t, _design_of(meta), cal),
                   offset=lambda meta: grid_offset(_design_of(meta), cal), kind="calibrated",
                   **kw)

    @classmethod
    def oracle(cls, design, n_views: int, **kw) -> "SegmentReconstructor":
        """The exact operator of ``design`` (on the ground-truth grid)."""
        from kaleidospec.pipeline import oracle_operator
        from sim.oracle import oracle_measurements

        op = oracle_operator(design, n_views)
        return cls(op, lambda frame, meta: oracle_measurements(frame, meta, design, n_views),
                   kind="oracle", **kw)

    def measurement(self, frame, metadata) -> np.ndarray:
        """The (K, Hv, Wm) measurement in the operator's units."""
        return self._measure(frame, metadata)

    def truth_on_grid(self, truth, metadata) -> np.ndarray:
        """The ground truth (v, v, L) on the reconstruction grid."""
        t = np.asarray(truth, np.float32)
        want = (self.op.ishape[1], self.op.ishape[2], self.op.ishape[0])
        if t.shape == want or self._to_grid is None:
            return t
        return self._to_grid(t, metadata)

    def grid_offset(self, metadata) -> tuple[float, float]:
        """(oy, ox): reconstruction pixel (y, x) is truth pixel (y + oy, x + ox)."""
        return (0.0, 0.0) if self._offset is None else self._offset(metadata)

    def solver_options(self) -> dict:
        """GAP-TV's step (computed on first use) and prox threads."""
        opts = {}
        if self.solver == "gap-tv":
            if self._step is None:
                from recon.solvers.base import preconditioned_norm_sq, safe_reciprocal

                phi_inv = safe_reciprocal(self.op.row_norms_sq(), np.float32)
                self._step = 1.0 / preconditioned_norm_sq(self.op, phi_inv, dtype=np.float32)
            opts["step"] = self._step
            if self.threads is not None:
                opts["threads"] = self.threads
        return opts

    def solve(self, g, *, iters: int, x0=None, mu: float = 0.0, callback=None
              ) -> tuple[np.ndarray, dict]:
        r"""Reconstruct one frame → (cube (H, W, L), info).

        ``x0`` (H, W, L) warm-starts the solver; ``mu`` > 0 (with ``x0``) adds the temporal
        term :math:`\mu\lVert f - x_0\rVert_1` (GAP-TV only, :mod:`recon.temporal`).
        """
        t0 = time.perf_counter()
        x0_bm = None if x0 is None else np.ascontiguousarray(
            np.moveaxis(np.asarray(x0, np.float32), 2, 0))
        g = np.asarray(g, np.float32)
        if mu > 0 and x0_bm is not None:
            from recon.temporal import gap_tv_temporal

            if self.solver != "gap-tv":
                raise InputError("the temporal TV term is implemented for gap-tv only")
            res = gap_tv_temporal(self.op, g, ref=x0_bm, mu=float(mu), iters=int(iters),
                                  tau=self.tau, x0=x0_bm, callback=callback,
                                  **self.solver_options())
        else:
            from recon.solvers import solve

            mu = 0.0
            res = solve(self.solver, self.op, g, iters=int(iters), tau=self.tau, x0=x0_bm,
                        callback=callback, **self.solver_options())
        cube = np.ascontiguousarray(np.moveaxis(res.x, 0, 2), dtype=np.float32)
        if not np.all(np.isfinite(cube)):
            raise RuntimeError(f"solver {self.solver!r} diverged (non-finite values)")
        return cube, {"iters": int(res.iterations), "wall_seconds": time.perf_counter() - t0,
                      "tau": self.tau, "mu": float(mu)}


def _frame_measurement(frame, metadata, cal, view_ids) -> np.ndarray:
    """Cut the views out of a raw frame and divide by its exposure factor ``radiance_scale``
    (as :func:`kaleidospec.pipeline.reconstruct_views`: the calibration divided its captures'
    out, so frames and calibration share one radiometric scale)."""
    from recon.calibration import measurements

    g = measurements(frame, cal, view_ids, metadata=metadata)
    s = (metadata or {}).get("radiance_scale")
    if s is not None:
        s = float(s)
        if not math.isfinite(s) or s <= 0:
            raise InputError(f"radiance_scale {s} in the frame's sidecar must be > 0")
        g /= np.float32(s)
    return g


def sector_colour_errors(est, truth, wavelengths, masks) -> list:
    r"""CIEDE2000 of each colour-wheel sector: the sector's mean spectrum against the truth's.

    As a spectroradiometer aimed at a sector would (the paper's check), the spectra are
    averaged over the sector's interior pixels (``masks`` (N, H, W), bool) first; both means
    are rendered with the exposure of the whole true frame (the 99th percentile of its
    luminance) and compared with :func:`recon.metrics.delta_e2000`.  Empty sectors give None.
    """
    from recon.metrics import cube_to_xyz, delta_e2000

    est = np.asarray(est, np.float64)
    truth = np.asarray(truth, np.float64)
    peak = float(np.percentile(cube_to_xyz(truth, wavelengths)[..., 1], 99.0))
    out = []
    for m in np.asarray(masks, bool):
        if not m.any():
            out.append(None)
            continue
        a = est[m].mean(axis=0)[None, None, :]
        b = truth[m].mean(axis=0)[None, None, :]
        out.append(float(delta_e2000(a, b, wavelengths, peak=peak)[0]))
    return out


def _sector_masker(desc: dict | None):
    if not desc or desc.get("kind") != "colorwheel":
        return None
    from scenes.animated import RotatingColorwheel

    return RotatingColorwheel(tuple(desc["shape"]), None, n_frames=desc["frames"],
                              fps=desc["fps"], exposure_ms=desc["exposure_ms"],
                              subframes=desc["subframes"], speed_deg_s=desc["speed_deg_s"],
                              angle0_deg=desc["angle0_deg"], **desc["wheel"])


def frame_metrics(cube, truth, wavelengths, sector_masks=None) -> dict:
    """:func:`recon.metrics.all_metrics` plus the per-sector CIEDE2000 when masks are given."""
    from recon.metrics import all_metrics

    m = all_metrics(cube, truth, wavelengths)
    if sector_masks is not None:
        de = sector_colour_errors(cube, truth, wavelengths, sector_masks)
        m["sector_delta_e2000"] = de
        vals = [v for v in de if v is not None]
        m["sector_delta_e2000_mean"] = float(np.mean(vals)) if vals else None
    return m


def reconstruct_segment(out_dir, start: int, stop: int, settings: dict, on_frame=None) -> dict:
    """Reconstruct frames ``start`` … ``stop − 1`` of a rendered sequence, chaining warm starts.

    The first frame of the segment starts cold (``cold_iters``); each later one starts from the
    previous reconstruction (``iters``).  Finished frames are skipped; after a skipped frame the
    next warm start reads its cube back.  Top-level and with plain arguments so that a process
    pool or a Dask worker can run it.

    Parameters
    ----------
    out_dir : path
    start, stop : int
    settings : dict
        ``operator`` (``calibrated``, default, or ``oracle``), ``calibration`` (path) or
        ``design`` (a ``Design.to_dict()``, for the oracle), ``views``, ``solver``, ``iters``,
        ``cold_iters``, ``tau``, ``mu``, ``threads``, ``animation`` (the scene's
        ``describe()``, for sector masks), ``wavelengths``.
    on_frame : callable, optional
        Called with the frame index after each frame is written (progress in this process).

    Returns
    -------
    dict
        ``done`` (frames reconstructed now), ``skipped``, ``seconds``.
    """
    from recon.io.cubes import read_cube, write_cube
    from recon.io.raw import read_raw

    lay = VideoLayout(out_dir)
    todo = [i for i in range(start, stop) if not lay.reconstructed(i)]
    summary = {"start": start, "stop": stop, "done": 0, "skipped": (stop - start) - len(todo),
               "seconds": 0.0}
    if not todo:
        return summary
    rec = _segment_reconstructor(settings)
    wl = np.asarray(settings["wavelengths"], np.float64)
    masker = _sector_masker(settings.get("animation"))
    offset = None
    prev = None
    prev_i = None
    t_seg = time.perf_counter()
    for i in todo:
        if i > start and prev_i != i - 1:
            prev, _ = read_cube(lay.cube(i - 1))  # resume: the warm start from disk
        elif i == start:
            prev = None
        frame, meta = read_raw(lay.raw(i))
        g = rec.measurement(frame, meta)
        warm = prev is not None
        iters = settings["iters"] if warm else settings["cold_iters"]
        cube, info = rec.solve(g, iters=iters, x0=prev,
                               mu=settings.get("mu", 0.0) if warm else 0.0)
        truth = rec.truth_on_grid(read_cube(lay.truth(i))[0], meta)
        masks = None
        if masker is not None:
            if offset is None:
                offset = rec.grid_offset(meta)
            masks = masker.sector_masks(i, grid_shape=cube.shape[:2], offset=offset)
        m = frame_metrics(cube, truth, wl, masks)
        write_cube(lay.cube(i), cube, wl)
        rec_info = {"frame": i, "time_s": meta.get("time_s"), "warm": warm,
                    "iters": int(info["iters"]), "solve_seconds": float(info["wall_seconds"]),
                    "segment": [start, stop], "views": int(settings["views"]),
                    "mu": float(info.get("mu", 0.0)), **m}
        _write_json(lay.metrics(i), rec_info)
        prev, prev_i = cube, i
        summary["done"] += 1
        if on_frame is not None:
            on_frame(i)
    summary["seconds"] = time.perf_counter() - t_seg
    return summary


def _segment_reconstructor(settings: dict) -> SegmentReconstructor:
    kw = {"solver": settings["solver"], "tau": settings.get("tau"),
          "threads": settings.get("threads")}
    if settings.get("operator", "calibrated") == "oracle":
        from sim.design import Design

        return SegmentReconstructor.oracle(Design.from_dict(settings["design"]),
                                           settings["views"], **kw)
    from recon.calibration import load_calibration

    return SegmentReconstructor.calibrated(load_calibration(settings["calibration"]),
                                           settings["views"], **kw)


def plan_segments(n_frames: int, segment_frames: int) -> list[list[int]]:
    """Split 0 … n_frames − 1 into consecutive ``[start, stop)`` segments of at most
    ``segment_frames`` frames."""
    n, s = int(n_frames), int(segment_frames)
    if s < 1:
        raise InputError(f"a segment must hold at least one frame, got {segment_frames}")
    return [[a, min(a + s, n)] for a in range(0, n, s)]


def _dask_client(address: str):
    try:
        from dask.distributed import Client
    except ImportError:
        raise InputError("--scheduler needs dask.distributed, which is not installed "
                         "(pip install 'dask[distributed]')") from None
    try:
        return Client(address, timeout="10s")
    except (OSError, TimeoutError) as err:
        raise InputError(f"cannot reach the Dask scheduler at {address} ({err})") from None


def reconstruct_sequence(out_dir, n_frames: int, segments, settings: dict, *,
                         workers: int | None = None, scheduler: str | None = None,
                         progress: bool = True, poll_s: float = 0.2) -> dict:
    """Reconstruct every frame of a rendered sequence, segment by segment.

    Segments with unfinished frames run in parallel: on a Dask cluster when ``scheduler``
    (``tcp://host:port``) is given, else in up to ``workers`` local processes (default: every
    core; 1 runs them in this process, one after the other).  Progress counts finished frames
    (their metrics files), so it is the same for every backend.

    Returns
    -------
    dict
        ``done``, ``skipped``, ``seconds`` (wall), ``backend``, ``workers``.
    """
    lay = VideoLayout(out_dir)
    pending = [seg for seg in segments
               if any(not lay.reconstructed(i) for i in range(seg[0], seg[1]))]
    already = lay.count_reconstructed(n_frames)
    ncpu = os.cpu_count() or 1
    workers = ncpu if workers is None else max(1, int(workers))
    backend = "dask" if scheduler else ("processes" if workers > 1 and len(pending) > 1
                                        else "serial")
    nproc = min(workers, len(pending)) if backend == "processes" else 1
    s = dict(settings)
    if s.get("threads") is None:
        # Processes × prox threads should not exceed the cores.
        s["threads"] = max(1, ncpu // nproc) if backend != "dask" else 1
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n_frames, initial=already, desc="reconstruct", unit="frame")
    t0 = time.perf_counter()
    results = []

    def tick():
        if bar is not None:
            bar.n = lay.count_reconstructed(n_frames)
            bar.refresh()

    try:
        if backend == "serial":
            for a, b in pending:
                results.append(reconstruct_segment(out_dir, a, b, s,
                                                   on_frame=lambda i: tick()))
        elif backend == "processes":
            import multiprocessing as mp
            from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

            # spawn: the parent may hold Mitsuba/LLVM threads, which fork would copy broken.
            with ProcessPoolExecutor(max_workers=nproc, mp_context=mp.get_context("spawn")) as ex:
                futs = {ex.submit(reconstruct_segment, str(out_dir), a, b, s) for a, b in pending}
                while futs:
                    finished, futs = wait(futs, timeout=poll_s, return_when=FIRST_COMPLETED)
                    for f in finished:
                        results.append(f.result())
                    tick()
        else:
            from concurrent.futures import FIRST_COMPLETED

            client = _dask_client(scheduler)
            try:
                from dask.distributed import wait as dwait

                futs = [client.submit(reconstruct_segment, str(Path(out_dir).resolve()), a, b, s,
                                      pure=False) for a, b in pending]
                remaining = set(futs)
                while remaining:
                    try:
                        res = dwait(list(remaining), timeout=poll_s,
                                    return_when=FIRST_COMPLETED)
                    except TimeoutError:
                        # Dask's wait raises when nothing finished within the poll interval
                        # (unlike concurrent.futures.wait): show the progress, wait again.
                        tick()
                        continue
                    for f in res.done:
                        results.append(f.result())
                    remaining = set(res.not_done)
                    tick()
            finally:
                client.close()
    finally:
        if bar is not None:
            tick()
            bar.close()
    done = lay.count_reconstructed(n_frames) - already
    return {"done": int(done), "skipped": int(already), "seconds": time.perf_counter() - t0,
            "backend": backend, "workers": nproc, "segments": len(pending)}


# ---------------------------------------------------------------------------------------------
# outputs of the whole sequence
# ---------------------------------------------------------------------------------------------
_CSV_KEYS = ("frame", "time_s", "warm", "iters", "solve_seconds", "psnr", "psnr_bandwise",
             "ssim", "sam_deg", "delta_e2000", "sector_delta_e2000_mean")


def write_summary(out_dir, n_frames: int) -> dict:
    """Gather the per-frame metrics into ``metrics.json`` (frames + means) and ``metrics.csv``."""
    from recon.io.atomic import write_text

    lay = VideoLayout(out_dir)
    frames = [read_json_object(lay.metrics(i)) for i in range(n_frames) if lay.metrics(i).exists()]
    summary: dict = {"frames": len(frames)}
    for k in ("psnr", "psnr_bandwise", "ssim", "sam_deg", "delta_e2000",
              "sector_delta_e2000_mean", "solve_seconds", "iters"):
        vals = [f[k] for f in frames if f.get(k) is not None]
        if vals:
            summary[f"mean_{k}"] = float(np.mean(vals))
    sectors = [f["sector_delta_e2000"] for f in frames if f.get("sector_delta_e2000")]
    if sectors:
        arr = np.array([[np.nan if v is None else v for v in s] for s in sectors], np.float64)
        summary["mean_sector_delta_e2000"] = [None if np.all(np.isnan(c)) else float(np.nanmean(c))
                                              for c in arr.T]
    _write_json(lay.root / "metrics.json", {"summary": summary, "frames": frames})
    n_sec = max((len(f.get("sector_delta_e2000") or []) for f in frames), default=0)
    buf = io.StringIO()
    wr = csv.writer(buf, lineterminator="\n")
    wr.writerow(list(_CSV_KEYS) + [f"sector_{k}_delta_e2000" for k in range(n_sec)])
    for f in frames:
        sec = list(f.get("sector_delta_e2000") or [])
        sec += [None] * (n_sec - len(sec))
        wr.writerow(["" if f.get(k) is None else f.get(k) for k in _CSV_KEYS]
                    + ["" if v is None else v for v in sec])
    write_text(lay.root / "metrics.csv", buf.getvalue())
    return summary


def write_video(out_dir, n_frames: int, fps: float, wavelengths, *, fmt: str = "gif",
                with_truth: bool = True, truth_to_grid=None) -> Path:
    """The sRGB video of the reconstructions (ground truth on the left when available).

    Every frame is rendered with one exposure, the 99th percentile of the luminance of the
    first true frame (or reconstruction), so brightness changes are the scene's own.  Animated
    GIF or WebP through imageio/Pillow, written atomically; frames whose cube is missing are
    left out.  ``truth_to_grid(truth)`` moves a truth cube onto the reconstruction grid when
    the two differ (the calibration's grid, :func:`kaleidospec.pipeline.truth_on_grid`).
    """
    import imageio.v3 as iio

    from recon.io.atomic import atomic_path
    from recon.io.cubes import read_cube
    from recon.metrics import cube_to_srgb, cube_to_xyz

    if fmt not in ("gif", "webp"):
        raise InputError(f"video format must be gif or webp, got {fmt!r}")
    lay = VideoLayout(out_dir)
    wl = np.asarray(wavelengths, np.float64)
    peak = None
    images = []
    for i in range(n_frames):
        if not lay.cube(i).exists():
            continue
        rec, _ = read_cube(lay.cube(i))
        parts = [rec]
        if with_truth and lay.truth(i).exists():
            truth, _ = read_cube(lay.truth(i))
            if truth.shape != rec.shape and truth_to_grid is not None:
                truth = truth_to_grid(truth)
            if truth.shape == rec.shape:
                parts = [truth, rec]
        if peak is None:
            peak = float(np.percentile(cube_to_xyz(parts[0], wl)[..., 1], 99.0)) or 1.0
        rgb = np.concatenate([cube_to_srgb(p, wl, peak=peak) for p in parts], axis=1)
        images.append(np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8))
    if not images:
        raise InputError(f"{out_dir}: no reconstructed frames to make a video of")
    path = lay.root / f"video.{fmt}"
    kw = {"duration": 1000.0 / float(fps), "loop": 0}
    if fmt == "webp":
        kw["lossless"] = True
    with atomic_path(path) as tmp:
        iio.imwrite(tmp, np.stack(images), extension=f".{fmt}", plugin="pillow", **kw)
    return path


# ---------------------------------------------------------------------------------------------
# the whole run (what `kaleidospec video` does)
# ---------------------------------------------------------------------------------------------
def _check_manifest(lay: VideoLayout, config: dict) -> dict | None:
    if not lay.manifest.exists():
        return None
    old = read_json_object(lay.manifest)
    prev = old.get("config", {})
    diff = sorted(k for k in set(prev) | set(config) if prev.get(k) != config.get(k))
    if diff:
        raise InputError(f"{lay.root} holds a video made with other settings (differs in "
                         f"{', '.join(diff)}); use another --out to start a new one")
    return old


def run_video(scene: str, out_dir, *, design: str = "small", overrides: dict | None = None,
              frames: int | None = None, fps: float = 10.0, views: int = 5,
              solver: str = "gap-tv", iters: int = 15, cold_iters: int = 50,
              tau: float | None = None, temporal: float = 0.0, seed: int = 0,
              noise: bool = True, subframes: int = 1, scene_params: dict | None = None,
              segment_frames: int | None = None, workers: int | None = None,
              scheduler: str | None = None, video_format: str = "gif",
              operator: str = "calibrated", progress: bool = True, cache_dir=None) -> dict:
    """Render and reconstruct a dynamic scene; resumes an interrupted run in ``out_dir``.

    Parameters
    ----------
    scene : str
        ``colorwheel``, ``moving_object`` or a folder of cube files.
    out_dir : path
        Output folder (see the module notes); created if missing.
    design, overrides : the design preset and its field overrides.
    frames : int, optional
        Number of frames (default 10; every file of a folder).
    fps : float
        Frame rate; the exposure is the design's ``exposure_ms`` (≤ 1000/fps).
    views : int
        Views used for reconstruction (1, 2, 3, 5, …; the first of centre, left, right, top,
        bottom).
    solver, iters, cold_iters, tau
        Solver, iterations of warm-started and of cold-started frames, TV weight.
    temporal : float
        Weight μ of the temporal term (0: off).
    seed, noise : sensor noise.
    subframes : int
        Midpoint-rule sub-frames per exposure (motion blur; 1 ignores it).
    scene_params : dict, optional
        Extra scene parameters (e.g. ``speed_deg_s`` of the colour wheel).
    segment_frames : int, optional
        Frames per segment (default: the frames shared evenly among the workers).
    workers : int, optional
        Local processes (default: all cores).
    scheduler : str, optional
        Dask scheduler address; the workers must see ``out_dir``.
    video_format : {"gif", "webp"}
    operator : {"calibrated", "oracle"}
        Reconstruct with the calibration (default, what the instrument does) or with the
        design's exact operator (for comparison).
    cache_dir : path, optional
        Calibration cache (:func:`kaleidospec.pipeline.calibrate`'s default if None).

    Returns
    -------
    dict
        Render and reconstruction statistics and the metrics summary.
    """
    from recon.app import solver_names
    from scenes.animated import get_animation
    from sim.design import get_design

    if solver not in solver_names():
        raise InputError(f"--solver must be one of {', '.join(solver_names())}, got {solver!r}")
    for name, v, lo in (("iters", iters, 1), ("cold-iters", cold_iters, 1), ("views", views, 1)):
        if isinstance(v, bool) or int(v) != v or v < lo:
            raise InputError(f"--{name} must be an integer >= {lo}, got {v!r}")
    if not (math.isfinite(float(temporal)) and temporal >= 0):
        raise InputError(f"--temporal must be >= 0, got {temporal}")
    if temporal > 0 and solver != "gap-tv":
        raise InputError("--temporal is implemented for the gap-tv solver only")
    if operator not in ("calibrated", "oracle"):
        raise InputError(f"--operator must be calibrated or oracle, got {operator!r}")
    if video_format not in ("gif", "webp"):
        raise InputError(f"--format must be gif or webp, got {video_format!r}")
    if scheduler is not None and not str(scheduler).startswith(("tcp://", "tls://", "inproc://",
                                                                "ucx://")):
        raise InputError(f"--scheduler must be an address like tcp://host:8786, got {scheduler!r}")
    d = get_design(design, overrides)
    if not 1 <= int(views) <= len(d.views):
        raise InputError(f"--views must be 1..{len(d.views)} for this design, got {views}")
    from sim.frame import scene_grid

    anim = get_animation(scene, scene_grid(d), d.wavelengths, n_frames=frames, fps=fps,
                         exposure_ms=d.exposure_ms, subframes=subframes, **(scene_params or {}))
    n = len(anim)
    ncpu = os.cpu_count() or 1
    nworkers = ncpu if workers is None else max(1, int(workers))
    if segment_frames is not None and (int(segment_frames) != segment_frames or segment_frames < 1):
        raise InputError(f"--segment must be an integer >= 1, got {segment_frames}")

    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder")
    lay = VideoLayout(out)
    config = {"scene": str(scene), "animation": anim.describe(), "design": design,
              "overrides": {k: str(val) for k, val in (overrides or {}).items()},
              "design_hash": d.hash, "views": int(views), "solver": solver,
              "iters": int(iters), "cold_iters": int(cold_iters), "tau": tau,
              "temporal": float(temporal), "seed": int(seed), "noise": bool(noise),
              "operator": operator}
    old = _check_manifest(lay, config)
    lay.make()

    renderer = FrameRenderer(d, anim.shape, anim.wavelengths, progress=progress)
    if old is not None:
        radiance_scale = float(old["radiance_scale"])
        segments = old["segments"]
        if segment_frames is not None and segments and \
                plan_segments(n, segment_frames) != segments:
            raise InputError(f"{out} was split into segments of {segments[0][1] - segments[0][0]} "
                             "frames; resume it with the same --segment")
    else:
        radiance_scale = renderer.exposure_for(anim.frame(0))
        seg = segment_frames if segment_frames is not None else max(1, math.ceil(n / nworkers))
        segments = plan_segments(n, seg)
        _write_json(lay.manifest, {"kind": "kaleidospec video", "config": config,
                                   "radiance_scale": radiance_scale, "segments": segments,
                                   "wavelengths_nm": [float(x) for x in anim.wavelengths],
                                   "frames": n, "fps": anim.fps,
                                   "exposure_ms": anim.exposure_ms})

    t0 = time.perf_counter()
    render_stats = render_sequence(anim, d, out, radiance_scale=radiance_scale, seed=seed,
                                   noise=noise, renderer=renderer, progress=progress,
                                   scene=str(scene))
    render_stats["wall_seconds"] = time.perf_counter() - t0

    settings = {"operator": operator, "views": int(views), "solver": solver,
                "iters": int(iters), "cold_iters": int(cold_iters), "tau": tau,
                "mu": float(temporal), "animation": anim.describe(),
                "wavelengths": [float(x) for x in anim.wavelengths]}
    if operator == "oracle":
        settings["design"] = d.to_dict()
    else:
        from kaleidospec.pipeline import calibrate

        calibrate(d, cache_dir=cache_dir, progress=progress)
        settings["calibration"] = str(_calibration_file(d, cache_dir))
    rec_stats = reconstruct_sequence(out, n, segments, settings, workers=nworkers,
                                     scheduler=scheduler, progress=progress)
    summary = write_summary(out, n)
    to_grid = None
    if operator == "calibrated":
        from kaleidospec.pipeline import calibrate, truth_on_grid

        cal = calibrate(d, cache_dir=cache_dir, progress=False)  # cached: a load
        to_grid = lambda t: truth_on_grid(t, d, cal)  # noqa: E731
    video = write_video(out, n, anim.fps, anim.wavelengths, fmt=video_format,
                        truth_to_grid=to_grid)
    return {"frames": n, "render": render_stats, "reconstruct": rec_stats, "summary": summary,
            "video": str(video), "out": str(out)}


def _calibration_file(design, cache_dir=None) -> Path:
    """Where the calibration of ``design`` is stored (workers load it from there)."""
    from recon.calibration import calibration_path
    from sim.transport import cache_dir as default_cache

    p = calibration_path(default_cache() if cache_dir is None else Path(cache_dir), design.hash)
    if not p.is_file():
        raise RuntimeError(f"the calibration of design {design.hash} is not at {p}")
    return p
