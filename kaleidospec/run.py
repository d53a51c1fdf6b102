"""One scene through the whole workflow: render → calibrate → reconstruct per view count →
evaluate → report (what ``kaleidospec run`` and ``demo`` do).

The stages are :mod:`kaleidospec.instrument`, :mod:`kaleidospec.calibrate`,
:mod:`kaleidospec.reconstruct`, :mod:`kaleidospec.evaluate` and :mod:`kaleidospec.report`;
this module only checks the inputs first and wires the stages into one output folder::

    raw.exr, raw.json             the simulated raw frame and its sidecar
    truth.exr, srgb_truth.png     the truth on the reconstruction grid
    cube_<n>views.exr             the reconstruction from the first n views
    srgb_<n>views.png             its sRGB rendering, with the truth's exposure
    bands.png, spectra.png        band montage; spectra of a few patches or points
    metrics.json                  per view count (and the exact operator's), the targets
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from kaleidospec.reconstruct import DEFAULTS
from recon.errors import InputError

__all__ = ["parse_views", "run"]


def parse_views(spec) -> tuple[int, ...]:
    """``"1,2,3,5,9"`` or a sequence → sorted distinct view counts in 1..9."""
    if isinstance(spec, str):
        parts = [p for p in spec.replace(" ", "").split(",") if p]
        try:
            counts = [int(p) for p in parts]
        except ValueError:
            raise InputError(f"--views must be a comma-separated list of counts 1..9, got "
                             f"{spec!r}") from None
    else:
        counts = [int(c) for c in spec]
    if not counts or any(not 1 <= c <= 9 for c in counts):
        raise InputError(f"view counts must be in 1..9, got {spec!r}")
    return tuple(sorted(set(counts)))


def run(scene, design, out_dir, *, views=(1, 2, 3, 5, 9), solver: str = DEFAULTS["solver"],
        iters: int = DEFAULTS["iters"], tol=DEFAULTS["tol"], tau=None, seed: int = 0,
        progress: bool = True, cache_dir=None, oracle: bool = True, figures: bool = True,
        raw=None, widen: bool = True, log=None, model: str | None = None,
        prior: str = "subspace-tv") -> dict:
    """Render ``scene``, calibrate (cached), reconstruct for every view count, write a report.

    Everything is written into a fresh temporary folder beside ``out_dir`` that replaces
    ``out_dir`` only at the end, so a failure leaves ``out_dir`` as it was; missing folders
    above it are created (:func:`recon.io.atomic.output_parents`).

    Parameters
    ----------
    scene : str or path
        Built-in scene name or cube file.
    design : sim.optics.design.Design
        Widened to the views the largest count needs
        (:func:`kaleidospec.instrument.design_for_views`).
    out_dir : path
    views : sequence of int
        View counts (1..9).
    solver, iters, tol, tau, prior, seed
        Reconstruction settings (:func:`kaleidospec.reconstruct.solve_views`: at most ``iters``
        iterations, fewer once the cube's relative change falls below ``tol``; the prior a
        :data:`recon.priors.PRIORS` name, ``subspace-tv`` by default as on the command line,
        ``tau`` its weight) and the sensor-noise seed.
    oracle : bool
        Also reconstruct with the exact operator (for the "within 1 dB" comparison).
    figures : bool
        Band montage and spectral plots (matplotlib).
    raw : (frame, metadata), optional
        Reconstruct this raw frame instead of rendering (the scene then only gives the truth);
        its ``design_hash`` must match ``design``'s calibration.
    widen : bool
        Widen the design to the views the largest count needs; ``False`` keeps it, and a count
        needing views it lacks is an error.
    log : callable, optional
        Called with each summary line (default: nothing).
    model : str, optional
        The calibrated forward model (:data:`kaleidospec.models.RUN_MODELS`; default
        :data:`kaleidospec.models.DEFAULT_MODEL`), calibrated if the cache lacks it.

    Returns
    -------
    dict
        The content of ``metrics.json``.
    """
    from kaleidospec import evaluate, instrument, report
    from kaleidospec.calibrate import calibrate, is_cached
    from kaleidospec.models import cube_grid, model_gains, model_of, truth_on_grid
    from kaleidospec.reconstruct import (check_oracle_solver, first_views, reconstruct_oracle,
                                         reconstruct_views)
    from recon.calibration import check_design
    from recon.view_ids import VIEW_ORDER
    from recon.io.atomic import atomic_dir, check_output, output_parents
    from recon.io.cubes import write_cube
    from recon.io.raw import write_raw
    from recon.priors import check_prior_name
    from recon.report import band_montage, spectra_plot, srgb_image, write_png

    counts = parse_views(views)
    check_prior_name(prior)
    if oracle:
        check_oracle_solver(solver)
    if widen:
        design = instrument.design_for_views(design, max(counts))
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"{out_dir}: exists and is not a folder")
    scene_path = Path(str(scene))
    if scene_path.exists() and out_dir.resolve() in (scene_path.resolve(),
                                                     *scene_path.resolve().parents):
        raise InputError(f"{out_dir}: would overwrite the input {scene}")
    check_output(out_dir, folder=True, parents=True)
    say = log or (lambda line: None)

    # --- inputs first: the scene (a bad cube fails before any long step) ----------------------
    t_start = time.perf_counter()
    frame, meta, truth, wl = instrument.render_scene(scene, design, seed=seed)
    # The scene frames' transport is not used again here (captures and the oracle have their
    # own realisations): 0.4 GB of the paper design's peak during the captures.
    instrument.release_transports("scene")
    if raw is not None:
        frame, meta = raw
        if meta.get("design_hash") not in (None, design.hash):
            raise InputError(f"raw frame was taken with design {meta.get('design_hash')}, but "
                             f"the calibration is for design {design.hash}")
        if np.shape(frame) != (design.sensor_height_px, design.sensor_width_px):
            raise InputError(f"raw frame shape {np.shape(frame)} is not the design's sensor")
    need = VIEW_ORDER[:max(counts)]
    missing = [v for v in need if v not in design.views]
    if missing:
        raise InputError(f"view(s) {missing} missing: the design traces views "
                         f"{list(design.views)}, {max(counts)} views need {list(need)}")
    cal_t0 = time.perf_counter()
    cached = is_cached(design, cache_dir)
    cal = calibrate(design, model=model, cache_dir=cache_dir, progress=progress)
    cal_seconds = time.perf_counter() - cal_t0
    check_design(cal, meta)
    model = model_of(cal, model)
    missing = [v for v in need if v not in cal.view_ids]
    if missing:
        raise InputError(f"view(s) {missing} missing from the calibration {list(cal.view_ids)}")

    with output_parents(out_dir), atomic_dir(out_dir) as tmp:
        write_raw(tmp / "raw.exr", frame, meta)
        # From the scene itself, built again (seconds) rather than held through the captures:
        # its mean on the design's grid has lost the detail within a pixel.  Each view count is
        # scored on the grid as its views see it; truth.exr is the grid as all of them see it.
        native = instrument.scene_cube(scene, design)[0]
        truths = {n: truth_on_grid(native, design, cal, model, first_views(n)) for n in counts}
        del native
        tg = truths[max(counts)]
        write_cube(tmp / "truth.exr", tg, wl)
        rgb_truth, peak = srgb_image(tg, wl)
        write_png(tmp / "srgb_truth.png", rgb_truth)
        result = {
            "scene": str(scene), "design": design.to_dict(), "design_hash": design.hash,
            "wavelengths_nm": [float(x) for x in wl], "solver": solver, "prior": prior,
            "iters": int(iters), "tol": tol, "tau": tau, "seed": int(seed), "model": model,
            "cube_shape": list(cube_grid(cal, model)) + [cal.n_bands],
            "calibration": {"cached": cached, "seconds": cal_seconds,
                            "view_ids": list(cal.view_ids),
                            "gains": model_gains(cal, model).tolist()},
            "views": {}, "oracle": {},
        }
        cubes = {}
        patches = evaluate.colorchecker_patches(design, cal, model) \
            if str(scene) == "colorchecker" else {}
        bar = report.progress_bar(len(counts) * (2 if oracle else 1), "reconstruct", progress)
        try:
            for n in counts:
                cube, info = reconstruct_views(frame, meta, cal, n, solver=solver, iters=iters,
                                               tol=tol, tau=tau, truth=truths[n], design=design,
                                               model=model, progress=progress, prior=prior)
                bar.update()
                cubes[n] = cube
                write_cube(tmp / f"cube_{n}views.exr", cube, wl)
                write_png(tmp / f"srgb_{n}views.png", srgb_image(cube, wl, peak)[0])
                result["views"][str(n)] = evaluate.scores(info, n)
                if patches:
                    result["views"][str(n)]["delta_e2000_patches"] = evaluate.patch_delta_e2000(
                        cube, info["truth_grid"], list(patches.values()), wl)
                if oracle:
                    ocube, oinfo = reconstruct_oracle(frame, meta, design, n, solver=solver,
                                                      iters=iters, tol=tol, tau=tau,
                                                      truth=truth, progress=progress,
                                                      prior=prior)
                    bar.update()
                    result["oracle"][str(n)] = evaluate.scores(oinfo, n)
                    del ocube, oinfo
                # A smaller count's truth is not read again (the figures use the largest's):
                # it goes before the next solve (84 MB on `paper`), with this solve's info.
                del cube, info
                if n != max(counts):
                    del truths[n]
        finally:
            bar.close()
        if figures:
            band_montage(tmp / "bands.png", tg, cubes, wl)
            spectra_plot(tmp / "spectra.png", tg, cubes, wl,
                         report.probe_boxes(scene, design, cal, model))
        result["targets"] = evaluate.targets(result)
        result["total_seconds"] = time.perf_counter() - t_start
        report.write_json(tmp / "metrics.json", report.finite(result))
    for line in report.summary_lines(result):
        say(line)
    return result
