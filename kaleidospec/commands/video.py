"""``kaleidospec video``: render and reconstruct a hyperspectral video (x, y, λ, t).

The engine is :mod:`kaleidospec.video`; this module parses options and prints a summary.  Run
again on the same ``--out`` folder, it resumes: finished frames are not redone.
"""

from __future__ import annotations

from typing import List, Optional

import typer

from kaleidospec.commands.prior_option import check_prior, prior_option


def _parse_params(items) -> dict:
    """``name=value`` pairs; values parsed as JSON when they can be (numbers, lists), else
    kept as strings."""
    import json

    from recon.errors import InputError

    out = {}
    for item in items or []:
        if "=" not in item:
            raise InputError(f"--param {item!r} is not of the form name=value")
        k, v = item.split("=", 1)
        if not k.strip():
            raise InputError(f"--param {item!r} has no name")
        try:
            out[k.strip()] = json.loads(v)
        except json.JSONDecodeError:
            out[k.strip()] = v
    return out


def video(
    scene: str = typer.Option(..., "--scene", help="colorwheel, moving_object, or a folder of "
                              "cube files (one per frame, natural sort order)."),
    out: str = typer.Option(..., "--out", help="Output folder (created; resumed if it holds "
                            "an interrupted run with the same settings)."),
    frames: Optional[int] = typer.Option(None, "--frames", help="Number of frames (default 10, "
                                         "or every file of a folder)."),
    fps: float = typer.Option(10.0, "--fps", help="Frame rate; the exposure is the design's "
                              "exposure_ms (--set exposure_ms=…), at most 1000/fps."),
    views: int = typer.Option(5, "--views", help="Views used to reconstruct (1, 2, 3, 5)."),
    design: str = typer.Option("small", "--design", help="Design preset: small or paper."),
    set_: Optional[List[str]] = typer.Option(None, "--set", help="Override a design field, "
                                             "name=value (repeatable)."),
    iters: int = typer.Option(15, "--iters", help="Iterations of a warm-started frame."),
    cold_iters: int = typer.Option(50, "--cold-iters", help="Iterations of a segment's first "
                                   "(cold-started) frame."),
    solver: Optional[str] = typer.Option(None, "--solver", help="gap-tv (default), twist or "
                                         "fista-tv (the default with --operator oracle, or "
                                         "where the lens blurs over a pixel, e.g. paper)."),
    tau: Optional[float] = typer.Option(None, "--tau", help="TV weight, >= 0 (default: "
                                        "follows the first frame's noise; gap-tv its own); "
                                        "another prior's strength (default: the prior's "
                                        "own)."),
    prior: str = prior_option(),
    temporal: float = typer.Option(0.0, "--temporal", help="Weight of the temporal TV term "
                                   "|f_t - f_(t-1)|_1 (0: off), added to the prior."),
    speed: Optional[float] = typer.Option(None, "--speed", help="Colour wheel speed, deg/s "
                                          "(default 36)."),
    subframes: int = typer.Option(1, "--subframes", help="Sub-frames averaged per exposure "
                                  "(motion blur; 1 ignores motion within the exposure)."),
    param: Optional[List[str]] = typer.Option(None, "--param", help="Scene parameter "
                                              "name=value (repeatable), e.g. sectors=6."),
    seed: int = typer.Option(0, "--seed", help="Sensor noise seed."),
    noise: bool = typer.Option(True, "--noise/--no-noise", help="Shot and read noise."),
    workers: Optional[int] = typer.Option(None, "--workers", help="Local processes "
                                          "(default: all cores)."),
    segment: Optional[int] = typer.Option(None, "--segment", help="Frames per segment (warm "
                                          "starts chain within a segment; default: frames / "
                                          "workers)."),
    scheduler: Optional[str] = typer.Option(None, "--scheduler", help="Dask scheduler "
                                            "address tcp://host:port (needs dask.distributed; "
                                            "the workers must see --out)."),
    fmt: str = typer.Option("gif", "--format", help="sRGB video format: gif or webp."),
    operator: str = typer.Option("calibrated", "--operator", help="calibrated (from the "
                                 "calibration captures) or oracle (the design's exact "
                                 "operator, for comparison)."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Progress bars."),
) -> None:
    """Render and reconstruct a dynamic scene frame by frame (4D hyperspectral video)."""
    import os

    from kaleidospec.instrument import parse_overrides
    from kaleidospec.video import run_video
    from recon.errors import InputError
    from recon.io.atomic import check_output, output_parents

    if frames is not None and frames < 1:
        raise InputError(f"--frames must be >= 1, got {frames}")
    check_prior(prior)
    if tau is not None:
        from recon.priors.tv import check_weight

        check_weight(tau, "--tau")
    params = _parse_params(param)
    if speed is not None:
        if scene != "colorwheel":
            raise InputError("--speed applies to the colorwheel scene only")
        params["speed_deg_s"] = speed
    if workers is not None and workers < 1:
        raise InputError(f"--workers must be >= 1, got {workers}")
    # A built-in scene's name is no file to protect (an --out of that name is fine).
    check_output(out, [scene if os.path.exists(scene) else None], folder=True, parents=True)
    with output_parents(out):
        res = run_video(scene, out, design=design, overrides=parse_overrides(set_),
                        frames=frames, fps=fps, views=views, solver=solver, iters=iters,
                        cold_iters=cold_iters, tau=tau, prior=prior, temporal=temporal,
                        seed=seed,
                        noise=noise, subframes=subframes, scene_params=params,
                        segment_frames=segment, workers=workers, scheduler=scheduler,
                        video_format=fmt, operator=operator, progress=progress)
    r, c, s = res["render"], res["reconstruct"], res["summary"]
    rate = (f", {r['rendered'] / r['seconds']:.1f} frames/s from the transport cache"
            if r["rendered"] and r["seconds"] > 0 else "")
    typer.echo(f"render: {r['rendered']} frames ({r['skipped']} already done){rate}")
    rrate = (f" in {c['seconds']:.1f} s, {c['done'] / c['seconds']:.2f} frames/s "
             f"({c['backend']}, {c['workers']} worker(s), {c['segments']} segment(s))"
             if c["done"] and c["seconds"] > 0 else "")
    typer.echo(f"reconstruct: {c['done']} frames ({c['skipped']} already done){rrate}")

    def f(k, fmt_=".2f"):
        v = s.get(k)
        return "n/a" if v is None else format(v, fmt_)
    typer.echo(f"mean over {s['frames']} frames: PSNR {f('mean_psnr')} dB, SAM "
               f"{f('mean_sam_deg')} deg, CIEDE2000 {f('mean_delta_e2000')}"
               + (f", sector CIEDE2000 {f('mean_sector_delta_e2000_mean')}"
                  if "mean_sector_delta_e2000_mean" in s else ""))
    typer.echo(f"wrote {res['out']} (cubes/, metrics.json, metrics.csv, {res['video']})")
