r"""Hyperspectral video (x, y, λ, t): dynamic scenes rendered and reconstructed frame by frame.

The stages are the stills' (:mod:`kaleidospec.instrument`, :mod:`kaleidospec.calibrate`,
:mod:`kaleidospec.reconstruct`, :mod:`kaleidospec.evaluate`, :mod:`kaleidospec.report`); this
module keeps the sequence's folder, its resume contract and the parallel segments.

Rendering.  The optics are linear and static, so a sequence reuses the design's transport:
:class:`kaleidospec.instrument.FrameRenderer` loads it once and each frame is only its pixel
integrals, the sensor's per-band QE, band width and Airy blur, and the shot/read noise draw.
Every frame of a sequence shares one exposure (``radiance_scale``, fixed from frame 0 unless
given), as a video camera at a fixed shutter and gain would, so brightness does not flicker.

Reconstruction.  Consecutive frames differ little, so frame :math:`t` starts from the
reconstruction of frame :math:`t-1` (a warm start) and needs fewer iterations (``iters``) than a
cold start (``cold_iters``, from :math:`H^\top\Phi^{-1}g`).  Optionally a temporal TV term
:math:`\mu\lVert f_t - \hat f_{t-1}\rVert_1` ties a frame to the previous reconstruction
(:mod:`recon.temporal`).  Warm starts chain frames only within a *segment*; segments are
independent, so a long sequence is split into segments that run in parallel: in local
processes (all cores by default) or, given a scheduler address, on a Dask cluster whose
workers see the same output folder (``dask.distributed`` is imported only then).  The operator
and the solver's step are made once per segment, not per frame
(:class:`kaleidospec.reconstruct.Reconstructor`; the step is read from the cache where a solve
with that calibration and those views kept it, :mod:`kaleidospec.solve_constants`).

Resume.  Every file is written atomically (temporary file + rename) and each stage of a frame
ends with a seal of its files' checksums (``checks/``): a raw frame is done when its seal matches
its image, sidecar and truth, a reconstructed frame when its seal matches its cube and metrics.
A new run on the same folder skips finished frames; an interrupted frame is redone from the
start, and so is one whose files no longer match their seal (one warning line names it); a
warm start after an interruption reads the previous frame's cube back (float32 EXR, lossless,
so the result is the same as without the interruption).  ``video.json`` pins the settings: a
run with other settings on the same folder is refused.

Layout of the output folder::

    video.json                 settings, exposure, segments (the resume contract)
    raw/frame_00000.exr|.json  raw frames + sidecars
    truth/frame_00000.exr      ground truth on the reconstruction grid (spectral EXR)
    cubes/frame_00000.exr      reconstructions (spectral EXR, recon.io.cubes.write_cube)
    metrics/frame_00000.json   per-frame metrics
    checks/raw_frame_00000.json, checks/cube_frame_00000.json
                               the SHA-256 of a frame's raw, sidecar and truth, and of its cube
                               and metrics (recon.io.cache.seal): the stages' done markers
    metrics.json, metrics.csv  all frames' metrics and their summary
    video.gif (or .webp)       sRGB: ground truth | reconstruction, side by side
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from recon.errors import InputError
from recon.io.arrays import read_json_object
from recon.kernels import cores

__all__ = ["VideoLayout", "render_sequence", "plan_segments", "reconstruct_segment",
           "reconstruct_sequence", "write_summary", "write_video", "run_video"]


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
        self.check_dir = self.root / "checks"
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
        for d in (self.root, self.raw_dir, self.truth_dir, self.cube_dir, self.metrics_dir,
                  self.check_dir):
            d.mkdir(parents=True, exist_ok=True)

    def check(self, stage: str, i: int) -> Path:
        """The seal of frame ``i``'s files of ``stage`` (``raw`` or ``cube``): their SHA-256,
        written after them (:func:`recon.io.cache.seal`), so it marks the stage done."""
        return self.check_dir / f"{stage}_{self.name(i)}.json"

    def files(self, stage: str, i: int) -> dict:
        """The files of frame ``i`` that the seal of ``stage`` covers."""
        if stage == "raw":
            return {"raw": self.raw(i), "sidecar": self.raw_sidecar(i), "truth": self.truth(i)}
        return {"cube": self.cube(i), "metrics": self.metrics(i)}

    def seal(self, stage: str, i: int) -> None:
        from recon.io.cache import seal

        self.check_dir.mkdir(exist_ok=True)
        seal(self.check(stage, i), self.files(stage, i), kind="video-frame",
             key=f"{stage}-{i}")

    def verified(self, stage: str, i: int) -> bool:
        """Whether frame ``i``'s ``stage`` is done and its files are the ones sealed; a seal
        that does not match (a file cut short, garbled or missing) is removed with one warning
        line, so the frame is redone."""
        from recon.io.cache import check_seal

        return check_seal(self.check(stage, i), self.files(stage, i), kind="video-frame",
                          key=f"{stage}-{i}")

    def rendered(self, i: int) -> bool:
        """Raw frame, sidecar, truth and their seal present (the seal is written last; see
        :meth:`verified` for the check of their contents)."""
        return self.check("raw", i).exists() and all(
            p.exists() for p in self.files("raw", i).values())

    def reconstructed(self, i: int) -> bool:
        """Cube, metrics and their seal present (the seal is written last; see
        :meth:`verified` for the check of their contents)."""
        return self.check("cube", i).exists() and all(
            p.exists() for p in self.files("cube", i).values())

    def count_reconstructed(self, n: int) -> int:
        return sum(self.reconstructed(i) for i in range(n))


# ---------------------------------------------------------------------------------------------
# rendering
# ---------------------------------------------------------------------------------------------
def render_sequence(anim, design, out_dir, *, radiance_scale: float, seed: int = 0,
                    noise: bool = True, renderer=None, progress: bool = True,
                    scene: str = "", first=None) -> dict:
    """Render every frame of ``anim`` not rendered yet into ``out_dir`` (see the layout).

    Frame *i* gets the noise seed ``[seed, i]``; its sidecar records ``frame``, ``time_s``
    (shutter opening) and the scene.  The ground truth (the cube on the centre view's grid,
    :func:`kaleidospec.instrument.ground_truth`) is written first, then the raw image, then
    its sidecar.  ``renderer`` (a :class:`kaleidospec.instrument.FrameRenderer`) is made for
    the design when not given.  ``first``, a list ``[cube, electrons]`` of frame 0 when the
    caller has computed them (:func:`run_video` sets the exposure from them), saves computing
    them again (the same frame; the electrons are scaled in place); it is emptied when they
    are taken, so that nothing holds frame 0's cube (0.34 GB at twice a `paper` view) while
    the others render.

    Returns
    -------
    dict
        ``rendered`` and ``skipped`` frame counts, ``seconds`` (rendering only, writes
        excluded) and ``write_seconds``.
    """
    from kaleidospec.instrument import FrameRenderer, ground_truth
    from recon.io.cubes import write_cube
    from recon.io.raw import write_raw

    lay = VideoLayout(out_dir)
    lay.make()
    todo = [i for i in range(len(anim)) if not lay.verified("raw", i)]
    stats = {"rendered": 0, "skipped": len(anim) - len(todo), "seconds": 0.0,
             "write_seconds": 0.0, "scene_seconds": 0.0}
    if not todo:
        return stats
    if renderer is None:
        renderer = FrameRenderer(design, anim.shape, anim.wavelengths, progress=progress)
    bar = None
    if progress:
        from recon.progress import progress_bar

        bar = progress_bar(total=len(anim), initial=stats["skipped"], desc="render",
                           unit="frame", leave=True)
    desc = anim.describe()
    try:
        for i in todo:
            t0 = time.perf_counter()
            ne = None
            if i == 0 and first:
                cube, ne = first
                first.clear()
            else:
                cube = anim.frame(i)
            t1 = time.perf_counter()
            frame = renderer.render(cube, radiance_scale=radiance_scale, seed=[int(seed), i],
                                    noise=noise, electrons=ne)
            del ne
            t2 = time.perf_counter()
            meta = renderer.metadata(radiance_scale=radiance_scale, seed=seed, noise=noise)
            meta.update(frame=i, time_s=anim.start_s(i), fps=anim.fps, scene=scene,
                        animation=desc, noise_seed=[int(seed), i])
            write_cube(lay.truth(i), ground_truth(design, cube), anim.wavelengths)
            write_raw(lay.raw(i), frame, meta)
            lay.seal("raw", i)
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
# reconstruction of a segment and of the sequence
# ---------------------------------------------------------------------------------------------
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
        ``cold_iters``, ``tau``, ``prior``, ``mu``, ``threads``, ``animation`` (the scene's
        ``describe()``, for sector masks), ``wavelengths``.
    on_frame : callable, optional
        Called with the frame index after each frame is written (progress in this process).

    Returns
    -------
    dict
        ``done`` (frames reconstructed now), ``skipped``, ``seconds``.
    """
    from kaleidospec.evaluate import frame_metrics, sector_masker
    from kaleidospec.report import write_json
    from recon.io.cubes import read_cube, write_cube
    from recon.io.raw import read_raw

    lay = VideoLayout(out_dir)
    todo = [i for i in range(start, stop) if not lay.verified("cube", i)]
    summary = {"start": start, "stop": stop, "done": 0, "skipped": (stop - start) - len(todo),
               "seconds": 0.0}
    if not todo:
        return summary
    rec = _segment_reconstructor(settings)
    if rec.tau is None:
        # A weight that follows the noise is the first frame's in every segment, so that the
        # sequence is solved with one weight whichever segment a frame falls in (a prior
        # other than TV sets its strength from that frame's noise too).
        rec.measurement(*read_raw(lay.raw(0)))
    wl = np.asarray(settings["wavelengths"], np.float64)
    masker = sector_masker(settings.get("animation"))
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
                    "tau": None if info["tau"] is None else float(info["tau"]),
                    "prior": info.get("prior", "tv"), "mu": float(info.get("mu", 0.0)), **m}
        write_json(lay.metrics(i), rec_info, sort_keys=True)
        lay.seal("cube", i)
        prev, prev_i = cube, i
        summary["done"] += 1
        if on_frame is not None:
            on_frame(i)
    summary["seconds"] = time.perf_counter() - t_seg
    return summary


def _segment_reconstructor(settings: dict):
    """The :class:`kaleidospec.reconstruct.Reconstructor` that ``settings`` describe."""
    from kaleidospec.reconstruct import Reconstructor

    kw = {"solver": settings["solver"], "tau": settings.get("tau"),
          "threads": settings.get("threads"), "prior": settings.get("prior", "tv")}
    if settings.get("operator", "calibrated") == "oracle":
        from kaleidospec.instrument import Design

        return Reconstructor.oracle(Design.from_dict(settings["design"]), settings["views"],
                                    **kw)
    from recon.calibration import load_calibration

    return Reconstructor.calibrated(load_calibration(settings["calibration"]),
                                    settings["views"], **kw)


def plan_segments(n_frames: int, segment_frames: int) -> list[list[int]]:
    """Split 0 … n_frames − 1 into consecutive ``[start, stop)`` segments of at most
    ``segment_frames`` frames."""
    n, s = int(n_frames), int(segment_frames)
    if s < 1:
        raise InputError(f"a segment must hold at least one frame, got {segment_frames}")
    return [[a, min(a + s, n)] for a in range(0, n, s)]


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
    # Checked once here (a damaged frame is redone); the progress below only counts seals.
    unsound = {i for a, b in segments for i in range(a, b) if not lay.verified("cube", i)}
    pending = [seg for seg in segments if any(i in unsound for i in range(seg[0], seg[1]))]
    already = lay.count_reconstructed(n_frames)
    ncpu = cores()
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
        from recon.progress import progress_bar

        bar = progress_bar(total=n_frames, initial=already, desc="reconstruct", unit="frame",
                           leave=True)
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
        else:
            from kaleidospec.parallel import map_unordered

            # Dask's workers may run elsewhere: they get the folder's absolute path.
            folder = str(Path(out_dir).resolve()) if backend == "dask" else str(out_dir)
            results.extend(map_unordered(reconstruct_segment,
                                         [(folder, a, b, s) for a, b in pending],
                                         workers=nproc, scheduler=scheduler, poll_s=poll_s,
                                         on_poll=tick))
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
def write_summary(out_dir, n_frames: int) -> dict:
    """Gather the per-frame metrics into ``metrics.json`` (frames + means,
    :func:`kaleidospec.evaluate.frame_means`) and ``metrics.csv``."""
    from kaleidospec.evaluate import frame_means
    from kaleidospec.report import write_frame_table, write_json

    lay = VideoLayout(out_dir)
    frames = [read_json_object(lay.metrics(i)) for i in range(n_frames) if lay.metrics(i).exists()]
    summary = frame_means(frames)
    write_json(lay.root / "metrics.json", {"summary": summary, "frames": frames},
               sort_keys=True)
    write_frame_table(lay.root / "metrics.csv", frames)
    return summary


def write_video(out_dir, n_frames: int, fps: float, wavelengths, *, fmt: str = "gif",
                with_truth: bool = True, truth_to_grid=None) -> Path:
    """The sRGB video of the reconstructions (ground truth on the left when available).

    Every frame is rendered with one exposure, the 99th percentile of the luminance of the
    first true frame (or reconstruction), so brightness changes are the scene's own.  Animated
    GIF or WebP (:func:`kaleidospec.report.write_animation`); frames whose cube is missing are
    left out.  ``truth_to_grid(truth)`` moves a truth cube onto the reconstruction grid when
    the two differ (the calibration's grid, :func:`kaleidospec.models.truth_on_grid`).
    """
    from kaleidospec.report import write_animation
    from recon.io.cubes import read_cube
    from recon.report import srgb_image

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
        row = []
        for p in parts:
            rgb, peak = srgb_image(p, wl, peak)   # the first picture's exposure, then kept
            row.append(rgb)
        images.append(np.concatenate(row, axis=1))
    if not images:
        raise InputError(f"{out_dir}: no reconstructed frames to make a video of")
    return write_animation(lay.root / f"video.{fmt}", images, fps, fmt)


# ---------------------------------------------------------------------------------------------
# the whole run (what `kaleidospec video` does)
# ---------------------------------------------------------------------------------------------
def _check_manifest(lay: VideoLayout, config: dict) -> dict | None:
    if not lay.manifest.exists():
        return None
    old = read_json_object(lay.manifest)
    prev = old.get("config", {})
    # A manifest from before priors were named had the TV prior.
    prev = {**prev, "prior": prev.get("prior", "tv")} if "prior" in config else prev
    diff = sorted(k for k in set(prev) | set(config) if prev.get(k) != config.get(k))
    if diff:
        raise InputError(f"{lay.root} holds a video made with other settings (differs in "
                         f"{', '.join(diff)}); use another --out to start a new one")
    return old


def default_solver(design, operator: str = "calibrated") -> str:
    """The video's solver when none is named: GAP-TV, or FISTA-TV with the exact operator
    (``operator="oracle"``) or a calibration that carries the lens's PSF
    (:func:`kaleidospec.calibrate.deconvolution_radii`): such a calibration blurs its rows
    together, like the exact operator, and GAP-TV's diagonal projection holds for neither."""
    from kaleidospec.calibrate import deconvolution_radii

    return "fista-tv" if operator == "oracle" or deconvolution_radii(design) is not None \
        else "gap-tv"


def run_video(scene: str, out_dir, *, design: str = "small", overrides: dict | None = None,
              frames: int | None = None, fps: float = 10.0, views: int = 5,
              solver: str | None = None, iters: int = 15, cold_iters: int = 50,
              tau: float | None = None, temporal: float = 0.0, seed: int = 0,
              noise: bool = True, subframes: int = 1, scene_params: dict | None = None,
              prior: str = "tv",
              segment_frames: int | None = None, workers: int | None = None,
              scheduler: str | None = None, video_format: str = "gif",
              operator: str = "calibrated", progress: bool = True, cache_dir=None) -> dict:
    r"""Render and reconstruct a dynamic scene; resumes an interrupted run in ``out_dir``.

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
        Solver (default GAP-TV with the calibration, FISTA-TV with the exact operator or with
        a calibration that carries the lens's PSF,
        :func:`kaleidospec.calibrate.deconvolution_radii`: GAP-TV projects onto each
        measurement row with :math:`\mathrm{diag}(HH^\top)^{-1}`, exact only when rows share
        no voxel, as in the shifted model; the exact operator's pixels share texels through
        their footprints, the smear and the blur, and GAP-TV diverges on it), iterations of
        warm-started and of cold-started frames, TV weight (another prior's strength).
    prior : str
        A :data:`recon.priors.PRIORS` name (default ``"tv"``).
    temporal : float
        Weight μ of the temporal term (0: off), added to the prior.
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
        Calibration cache (:func:`kaleidospec.calibrate.calibrate`'s default if None).

    Returns
    -------
    dict
        Render and reconstruction statistics and the metrics summary.
    """
    from kaleidospec import instrument
    from kaleidospec.calibrate import calibrate, calibration_file
    from kaleidospec.report import write_json
    from recon.app import solver_names

    from recon.priors import check_prior_name
    from recon.priors.tv import check_weight

    if operator not in ("calibrated", "oracle"):
        raise InputError(f"--operator must be calibrated or oracle, got {operator!r}")
    check_prior_name(prior)
    if tau is not None:
        check_weight(tau, "--tau")
    d = instrument.get_design(design, overrides)
    if solver is None:
        solver = default_solver(d, operator)
    if solver not in solver_names():
        raise InputError(f"--solver must be one of {', '.join(solver_names())}, got {solver!r}")
    if operator == "oracle":
        from kaleidospec.reconstruct import check_oracle_solver

        check_oracle_solver(solver)
    for name, v, lo in (("iters", iters, 1), ("cold-iters", cold_iters, 1), ("views", views, 1)):
        if isinstance(v, bool) or int(v) != v or v < lo:
            raise InputError(f"--{name} must be an integer >= {lo}, got {v!r}")
    if not (math.isfinite(float(temporal)) and temporal >= 0):
        raise InputError(f"--temporal must be >= 0, got {temporal}")
    if video_format not in ("gif", "webp"):
        raise InputError(f"--format must be gif or webp, got {video_format!r}")
    if scheduler is not None and not str(scheduler).startswith(("tcp://", "tls://", "inproc://",
                                                                "ucx://")):
        raise InputError(f"--scheduler must be an address like tcp://host:8786, got {scheduler!r}")
    if not 1 <= int(views) <= len(d.views):
        raise InputError(f"--views must be 1..{len(d.views)} for this design, got {views}")
    anim = instrument.animation(scene, d, n_frames=frames, fps=fps, subframes=subframes,
                                **(scene_params or {}))
    n = len(anim)
    ncpu = cores()
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
              "prior": prior, "temporal": float(temporal), "seed": int(seed),
              "noise": bool(noise), "operator": operator}
    old = _check_manifest(lay, config)
    lay.make()

    renderer = instrument.FrameRenderer(d, anim.shape, anim.wavelengths, progress=progress)
    first = None
    if old is not None:
        radiance_scale = float(old["radiance_scale"])
        segments = old["segments"]
        if segment_frames is not None and segments and \
                plan_segments(n, segment_frames) != segments:
            raise InputError(f"{out} was split into segments of {segments[0][1] - segments[0][0]} "
                             "frames; resume it with the same --segment")
    else:
        # Frame 0's electrons set the exposure, and render frame 0 (not computed twice).
        cube0 = anim.frame(0)
        first = [cube0, renderer.electrons(cube0)]
        radiance_scale = renderer.exposure_for(cube0, electrons=first[1])
        del cube0                    # render_sequence empties `first`: held nowhere after
        seg = segment_frames if segment_frames is not None else max(1, math.ceil(n / nworkers))
        segments = plan_segments(n, seg)
        write_json(lay.manifest, {"kind": "kaleidospec video", "config": config,
                                  "radiance_scale": radiance_scale, "segments": segments,
                                  "wavelengths_nm": [float(x) for x in anim.wavelengths],
                                  "frames": n, "fps": anim.fps,
                                  "exposure_ms": anim.exposure_ms}, sort_keys=True)

    t0 = time.perf_counter()
    render_stats = render_sequence(anim, d, out, radiance_scale=radiance_scale, seed=seed,
                                   noise=noise, renderer=renderer, progress=progress,
                                   scene=str(scene), first=first)
    del first
    render_stats["wall_seconds"] = time.perf_counter() - t0

    settings = {"operator": operator, "views": int(views), "solver": solver,
                "iters": int(iters), "cold_iters": int(cold_iters), "tau": tau,
                "prior": prior, "mu": float(temporal), "animation": anim.describe(),
                "wavelengths": [float(x) for x in anim.wavelengths]}
    cal = None
    if operator == "oracle":
        settings["design"] = d.to_dict()
    else:
        cal = calibrate(d, cache_dir=cache_dir, progress=progress)
        settings["calibration"] = str(calibration_file(d, cache_dir))
    rec_stats = reconstruct_sequence(out, n, segments, settings, workers=nworkers,
                                     scheduler=scheduler, progress=progress)
    summary = write_summary(out, n)
    to_grid = None
    if operator == "calibrated":
        from kaleidospec.models import truth_mover
        from kaleidospec.reconstruct import first_views

        # Where the grid lies on the scene is computed once for all the frames.
        to_grid = truth_mover(d, cal, view_ids=first_views(views))
    video = write_video(out, n, anim.fps, anim.wavelengths, fmt=video_format,
                        truth_to_grid=to_grid)
    return {"frames": n, "render": render_stats, "reconstruct": rec_stats, "summary": summary,
            "video": str(video), "out": str(out)}
