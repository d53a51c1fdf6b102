"""The video engine: rendering from the cache, warm starts, segments, resume, outputs, CLI.

The reconstruction tests use a small synthetic calibration (two views, 32×32×4, random
per-band mask images) and frames made with its own operator, so they need neither Mitsuba nor
the calibration renders; the rendering tests use a reduced design and a temporary
``KALEIDOSPEC_CACHE``.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from recon.errors import InputError
from recon.io.cubes import read_cube, write_cube
from recon.io.raw import write_raw
from recon.metrics import psnr

H = W = 32
L = 4
WL = np.array([450.0, 525.0, 600.0, 675.0])
N_FRAMES = 4


# ------------------------------------------------------------------ a synthetic instrument
def _calibration():
    from recon.calibration.store import Calibration

    rng = np.random.default_rng(3)
    offsets = np.array([[0, 1, 2, 3], [3, 2, 1, 0]], np.float64)
    wm = W + 3
    masks = (rng.random((2, L, H, wm)) < 0.5).astype(np.float32)
    return Calibration(view_ids=(0, 1), view_boxes=[[0, 0, H, wm], [H + 4, 0, H, wm]],
                       homographies=np.stack([np.eye(3)] * 2), mask_images=masks,
                       offsets=offsets, gains=np.ones(L), wavelengths=WL, cube_shape=(H, W, L))


def _truth(i):
    """A bright square moving 1 px per frame over a smooth background."""
    y, x = np.mgrid[0:H, 0:W] / H
    c = np.empty((H, W, L), np.float32)
    for l in range(L):
        c[:, :, l] = 0.2 + 0.2 * x * (l + 1) / L + 0.1 * y
    c[8:18, 6 + i:16 + i, :] += np.linspace(0.6, 0.2, L)[None, None, :]
    return c


@pytest.fixture
def sequence(tmp_path):
    """A rendered sequence (raw frames + truth) of the synthetic instrument and its settings."""
    from kaleidospec.reconstruct import calibrated_operator
    from kaleidospec.video import VideoLayout
    from recon.calibration import save_calibration

    cal = _calibration()
    cal_path = tmp_path / "cal.npz"
    save_calibration(cal_path, cal)
    op = calibrated_operator(cal, (0, 1))
    out = tmp_path / "video"
    lay = VideoLayout(out)
    lay.make()
    rng = np.random.default_rng(0)
    for i in range(N_FRAMES):
        t = _truth(i)
        g = op.forward(np.ascontiguousarray(np.moveaxis(t, 2, 0)))
        g += rng.normal(0, 0.003, g.shape).astype(np.float32)
        frame = np.zeros((2 * H + 4, W + 3), np.float32)
        frame[:H] = g[0]
        frame[H + 4:] = g[1]
        write_cube(lay.truth(i), t, WL)
        write_raw(lay.raw(i), frame, {"radiance_scale": 1.0, "time_s": i / 10})
    settings = {"calibration": str(cal_path), "views": 2, "solver": "gap-tv", "iters": 10,
                "cold_iters": 40, "tau": 0.02, "mu": 0.0, "animation": None,
                "wavelengths": WL.tolist()}
    return out, cal, settings


def _frame_problem(out, cal, i):
    from kaleidospec.reconstruct import Reconstructor
    from kaleidospec.video import VideoLayout
    from recon.io.raw import read_raw

    rec = Reconstructor.calibrated(cal, 2, tau=0.02)
    frame, meta = read_raw(VideoLayout(out).raw(i))
    return rec, rec.measurement(frame, meta), _truth(i)


def _iters_to_reach(rec, g, truth, target, x0=None, cap=200):
    """Iterations until the PSNR first reaches ``target`` (cap + 1 if never)."""
    hit = []

    def cb(it, x, info):
        if psnr(np.moveaxis(x, 0, 2), truth) >= target:
            hit.append(it)
            return True
        return None
    rec.solve(g, iters=cap, x0=x0, callback=cb)
    return hit[0] if hit else cap + 1


def test_warm_start_needs_fewer_iterations_for_the_same_accuracy(sequence):
    """Along a chain (frame 0 cold, then warm starts), each frame reaches the accuracy of a
    50-iteration cold start (less 0.5 dB) in fewer iterations from the previous frame."""
    out, cal, _ = sequence
    rec, g, t = _frame_problem(out, cal, 0)
    prev, _ = rec.solve(g, iters=40)
    counts = []
    for i in range(1, N_FRAMES):
        _, g, t = _frame_problem(out, cal, i)
        cold50, _ = rec.solve(g, iters=50)
        target = psnr(cold50, t) - 0.5
        counts.append((_iters_to_reach(rec, g, t, target, x0=prev),
                       _iters_to_reach(rec, g, t, target)))
        prev, info = rec.solve(g, iters=15, x0=prev)
        assert info["iters"] == 15
    for n_warm, n_cold in counts:
        assert n_warm < n_cold <= 50
    # Once the chain runs, the saving is large.
    assert counts[-1][0] <= 0.5 * counts[-1][1]


def test_segment_resumes_without_redoing_finished_frames(sequence):
    from kaleidospec.video import VideoLayout, reconstruct_sequence

    out, _, settings = sequence
    lay = VideoLayout(out)
    r = reconstruct_sequence(out, N_FRAMES, [[0, N_FRAMES]], settings, workers=1,
                             progress=False)
    assert r["done"] == N_FRAMES and r["backend"] == "serial"
    stamp = {i: (lay.cube(i).stat().st_mtime_ns, lay.metrics(i).stat().st_mtime_ns)
             for i in range(N_FRAMES)}
    first = {i: read_cube(lay.cube(i))[0] for i in range(N_FRAMES)}
    m = [json.loads(lay.metrics(i).read_text()) for i in range(N_FRAMES)]
    assert [x["warm"] for x in m] == [False, True, True, True]
    assert [x["iters"] for x in m] == [40, 10, 10, 10]
    assert all(x["psnr"] > 25 for x in m)

    # An interrupted run: frame 2 lost its metrics (its marker), frame 3 its cube.
    lay.metrics(2).unlink()
    lay.cube(3).unlink()
    r = reconstruct_sequence(out, N_FRAMES, [[0, N_FRAMES]], settings, workers=1,
                             progress=False)
    assert r["done"] == 2 and r["skipped"] == 2
    for i in (0, 1):
        assert (lay.cube(i).stat().st_mtime_ns, lay.metrics(i).stat().st_mtime_ns) == stamp[i]
    for i in (2, 3):
        assert lay.reconstructed(i)
        # The warm start read back from disk gives the very same frames.
        np.testing.assert_array_equal(read_cube(lay.cube(i))[0], first[i])
    # Nothing half-written is left behind.
    assert not [p for p in out.rglob(".*")]
    # A third run has nothing to do.
    assert reconstruct_sequence(out, N_FRAMES, [[0, N_FRAMES]], settings, workers=1,
                                progress=False)["done"] == 0


def test_parallel_segments_match_serial(sequence, tmp_path):
    import shutil

    from kaleidospec.video import VideoLayout, reconstruct_sequence

    out, _, settings = sequence
    other = tmp_path / "copy"
    shutil.copytree(out, other)
    segs = [[0, 2], [2, 4]]
    a = reconstruct_sequence(out, N_FRAMES, segs, settings, workers=1, progress=False)
    b = reconstruct_sequence(other, N_FRAMES, segs, settings, workers=2, progress=False)
    assert a["backend"] == "serial" and b["backend"] == "processes" and b["workers"] == 2
    la, lb = VideoLayout(out), VideoLayout(other)
    for i in range(N_FRAMES):
        np.testing.assert_array_equal(read_cube(la.cube(i))[0], read_cube(lb.cube(i))[0])
    warm = [json.loads(lb.metrics(i).read_text())["warm"] for i in range(N_FRAMES)]
    assert warm == [False, True, False, True]  # each segment starts cold


def test_segments_run_on_a_dask_cluster(sequence, tmp_path):
    """`--scheduler` runs the segments on a Dask cluster (a local one on loopback here) and
    gives the same cubes as the serial engine."""
    import shutil

    distributed = pytest.importorskip("distributed")
    from kaleidospec.video import VideoLayout, reconstruct_sequence

    out, _, settings = sequence
    other = tmp_path / "dask"
    shutil.copytree(out, other)
    segs = [[0, 2], [2, 4]]
    a = reconstruct_sequence(out, N_FRAMES, segs, settings, workers=1, progress=False)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  host="127.0.0.1", dashboard_address=None) as cluster:
        b = reconstruct_sequence(other, N_FRAMES, segs, settings, progress=False,
                                 scheduler=cluster.scheduler_address)
    assert a["backend"] == "serial" and b["backend"] == "dask"
    la, lb = VideoLayout(out), VideoLayout(other)
    for i in range(N_FRAMES):
        np.testing.assert_array_equal(read_cube(la.cube(i))[0], read_cube(lb.cube(i))[0])


def test_summary_and_video(sequence):
    import imageio.v3 as iio

    from kaleidospec.video import reconstruct_sequence, write_summary, write_video

    out, _, settings = sequence
    reconstruct_sequence(out, N_FRAMES, [[0, N_FRAMES]], settings, workers=1, progress=False)
    s = write_summary(out, N_FRAMES)
    data = json.loads((out / "metrics.json").read_text())
    assert s["frames"] == N_FRAMES == len(data["frames"])
    assert s["mean_psnr"] == pytest.approx(np.mean([f["psnr"] for f in data["frames"]]))
    rows = (out / "metrics.csv").read_text().strip().splitlines()
    assert len(rows) == N_FRAMES + 1 and rows[0].startswith("frame,")
    path = write_video(out, N_FRAMES, 10, WL)
    frames = iio.imread(path, index=None)
    assert frames.shape[0] == N_FRAMES and frames.shape[1:3] == (H, 2 * W)


def test_temporal_term_with_any_solver_records_the_prior(sequence):
    """The temporal term goes with FISTA too (as a prior around TV); each frame's metrics say
    which prior and which temporal weight it was solved with."""
    from kaleidospec.video import VideoLayout, reconstruct_segment

    out, _, settings = sequence
    lay = VideoLayout(out)
    for i in (2, 3):
        lay.cube(i).unlink(missing_ok=True)
        lay.metrics(i).unlink(missing_ok=True)
    reconstruct_segment(out, 2, 4, dict(settings, solver="fista-tv", iters=3, cold_iters=3,
                                         mu=0.05, prior="tv"))
    m = [json.loads(lay.metrics(i).read_text()) for i in (2, 3)]
    assert [f["prior"] for f in m] == ["tv", "tv"]
    assert [f["mu"] for f in m] == [0.0, 0.05]       # the cold first frame has no reference
    assert all(np.isfinite(f["psnr"]) for f in m)


def test_temporal_term():
    from recon.operators import kaleidoscope_cassi
    from recon.solvers import solve
    from recon.temporal import gap_tv_temporal, temporal_prox

    v = np.array([0.0, 0.5, 1.0, -1.0], np.float32)
    r = np.array([0.1, 0.0, 0.0, 0.0], np.float32)
    np.testing.assert_allclose(temporal_prox(v, r, 0.2), [0.1, 0.3, 0.8, -0.8], atol=1e-7)
    np.testing.assert_array_equal(temporal_prox(v, r, 0.0), v)

    rng = np.random.default_rng(1)
    op = kaleidoscope_cassi((rng.random((2, H, W)) < 0.5).astype(np.float32), [0, 1, 2, 3], 2)
    t0, t1 = (np.ascontiguousarray(np.moveaxis(_truth(i), 2, 0)) for i in (0, 1))
    g = op.forward(t1) + rng.normal(0, 0.01, op.oshape).astype(np.float32)
    # mu = 0 is GAP-TV itself.
    a = gap_tv_temporal(op, g, ref=t0, mu=0.0, iters=8, tau=0.05, step=0.5).x
    b = solve("gap-tv", op, g, iters=8, tau=0.05, x0=t0, step=0.5).x
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)
    # A large mu keeps the reference wherever the change is small.
    c = gap_tv_temporal(op, g, ref=t0, mu=10.0, iters=8, tau=0.05, step=0.5).x
    np.testing.assert_allclose(c, t0, atol=1e-6)
    with pytest.raises(InputError):
        gap_tv_temporal(op, g, ref=t0[:, :5], mu=0.1)


# ------------------------------------------------------------------ rendering (Mitsuba)
@pytest.mark.mitsuba
def test_render_sequence_resumes(tiny, tmp_path):
    from kaleidospec.instrument import FrameRenderer
    from kaleidospec.video import VideoLayout, render_sequence
    from recon.io.raw import read_raw
    from scenes.animated import RotatingColorwheel

    v = tiny.view_size_px
    anim = RotatingColorwheel((v, v), tiny.wavelengths, n_frames=3, speed_deg_s=45)
    r = FrameRenderer(tiny, (v, v), tiny.wavelengths)
    s = r.exposure_for(anim.frame(0))
    out = tmp_path / "v"
    st = render_sequence(anim, tiny, out, radiance_scale=s, renderer=r, progress=False)
    assert st["rendered"] == 3 and st["skipped"] == 0
    lay = VideoLayout(out)
    stamp = {i: lay.raw(i).stat().st_mtime_ns for i in range(3)}
    frame1, meta1 = read_raw(lay.raw(1))
    assert meta1["frame"] == 1 and meta1["time_s"] == pytest.approx(0.1)
    assert meta1["radiance_scale"] == s and meta1["design_hash"] == tiny.hash
    lay.raw_sidecar(1).unlink()  # interrupted between the image and its sidecar
    st = render_sequence(anim, tiny, out, radiance_scale=s, renderer=r, progress=False)
    assert st["rendered"] == 1 and st["skipped"] == 2
    assert lay.raw(0).stat().st_mtime_ns == stamp[0]
    assert lay.raw(2).stat().st_mtime_ns == stamp[2]
    again, _ = read_raw(lay.raw(1))
    np.testing.assert_array_equal(again, frame1)  # same seed [seed, frame]
    assert not [p for p in out.rglob(".*")]


def test_first_frame_from_the_exposures_electrons_is_the_same(tiny, tmp_path):
    """``run_video`` sets the exposure from frame 0's electrons and hands them to
    ``render_sequence`` (``first``), which renders frame 0 from them: the same raw frame as
    computing them again, and every other frame as before."""
    from kaleidospec.instrument import FrameRenderer
    from kaleidospec.video import VideoLayout, render_sequence
    from recon.io.raw import read_raw
    from scenes.animated import RotatingColorwheel
    from sim.frame import exposure

    v = tiny.view_size_px
    anim = RotatingColorwheel((v, v), tiny.wavelengths, n_frames=2, speed_deg_s=45)
    r = FrameRenderer(tiny, (v, v), tiny.wavelengths)
    s = r.exposure_for(anim.frame(0))
    cube0 = anim.frame(0)
    ne0 = r.electrons(cube0)
    assert exposure(ne0, tiny) == s == r.exposure_for(cube0, electrons=ne0)
    a, b = tmp_path / "a", tmp_path / "b"
    render_sequence(anim, tiny, a, radiance_scale=s, renderer=r, progress=False)
    first = [cube0, ne0]
    render_sequence(anim, tiny, b, radiance_scale=s, renderer=r, progress=False, first=first)
    assert first == []                   # taken: the caller holds frame 0's cube no longer
    for i in range(2):
        fa, ma = read_raw(VideoLayout(a).raw(i))
        fb, mb = read_raw(VideoLayout(b).raw(i))
        np.testing.assert_array_equal(fa, fb)
        assert ma == mb
        np.testing.assert_array_equal(read_cube(VideoLayout(a).truth(i))[0],
                                      read_cube(VideoLayout(b).truth(i))[0])


# ------------------------------------------------------------------ bad input
def _cli(argv, capsys):
    from kaleidospec.cli import main

    with pytest.raises(SystemExit) as exc:
        main(argv)
    out, err = capsys.readouterr()
    return exc.value.code, out, err


def test_cli_bad_cube_folders_exit_2(tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    shapes = tmp_path / "shapes"
    shapes.mkdir()
    np.savez(shapes / "a.npz", cube=np.ones((8, 8, 6), np.float32), wavelengths=np.arange(6) * 50 + 450.0)
    np.savez(shapes / "b.npz", cube=np.ones((9, 8, 6), np.float32), wavelengths=np.arange(6) * 50 + 450.0)
    nan = tmp_path / "nan"
    nan.mkdir()
    c = np.ones((8, 8, 6), np.float32)
    c[0, 0, 0] = np.inf
    np.savez(nan / "a.npz", cube=c, wavelengths=np.arange(6) * 50 + 450.0)
    for folder, msg in ((empty, "no cube files"), (shapes, "shape"), (nan, "NaN|non-finite")):
        out = tmp_path / f"out_{folder.name}"
        code, stdout, err = _cli(["video", "--scene", str(folder), "--out", str(out),
                                  "--no-progress"], capsys)
        assert code == 2, err
        assert err.startswith("kaleidospec: error:") and len(err.strip().splitlines()) == 1
        import re

        assert re.search(msg, err)
        assert not out.exists()


def test_cli_bad_options_exit_2(tmp_path, capsys):
    base = ["video", "--scene", "colorwheel", "--out", str(tmp_path / "o"), "--no-progress"]
    for extra in (["--fps", "20"],            # 100 ms exposure > 50 ms frame period
                  ["--views", "0"], ["--iters", "0"], ["--solver", "nope"],
                  ["--temporal", "-1"], ["--scheduler", "localhost:1"], ["--format", "mp4"],
                  ["--param", "spin=2"], ["--frames", "0"],
                  # GAP-TV diverges on the exact operator (its rows share texels).
                  ["--operator", "oracle", "--solver", "gap-tv"]):
        code, _, err = _cli(base + extra, capsys)
        assert code == 2, (extra, err)
        assert len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "o").exists()


def test_other_settings_in_the_same_folder_are_refused(tmp_path):
    from kaleidospec.video import run_video

    out = tmp_path / "o"
    out.mkdir()
    (out / "video.json").write_text(json.dumps({"config": {"scene": "moving_object"}}))
    with pytest.raises(InputError, match="other settings"):
        run_video("colorwheel", out, frames=2, progress=False)


def test_default_solver_follows_the_calibrated_model():
    """Where the calibration carries the lens's PSF (``paper``) the default solver is FISTA-TV,
    as with the exact operator; on ``small`` GAP-TV stays."""
    from kaleidospec.calibrate import deconvolution_radii
    from kaleidospec.video import default_solver
    from sim.optics.design import get_design

    assert deconvolution_radii(get_design("small")) is None
    radii = deconvolution_radii(get_design("paper"))
    assert radii is not None and radii.min() > 1.0
    assert default_solver(get_design("paper")) == "fista-tv"
    assert default_solver(get_design("small")) == "gap-tv"
    assert default_solver(get_design("small"), "oracle") == "fista-tv"


def test_every_segment_takes_the_first_frames_weight(sequence, tmp_path):
    """With FISTA-TV every segment solves with the first frame's noise-following weight (a
    calibration with a photon-transfer curve), the fixed one without a curve; GAP-TV keeps its
    own.  The weight each frame was solved with is in its metrics."""
    import dataclasses

    from kaleidospec.reconstruct import Reconstructor, tv_weight
    from kaleidospec.video import VideoLayout, reconstruct_segment
    from recon.calibration import save_calibration
    from recon.io.raw import read_raw

    out, cal, settings = sequence
    lay = VideoLayout(out)

    def taus(extra):
        for i in (2, 3):
            lay.cube(i).unlink(missing_ok=True)
            lay.metrics(i).unlink(missing_ok=True)
        reconstruct_segment(out, 2, 4, dict(settings, iters=2, cold_iters=2, **extra))
        return [json.loads(lay.metrics(i).read_text())["tau"] for i in (2, 3)]

    assert taus({"solver": "gap-tv", "tau": None}) == \
        pytest.approx([tv_weight("gap-tv", None, 2)] * 2)
    fista = {"solver": "fista-tv", "tau": None}
    assert taus(fista) == pytest.approx([tv_weight("fista-tv", None, 2)] * 2)
    noisy = dataclasses.replace(cal, noise=[0.3, 5.0])
    save_calibration(tmp_path / "noisy.npz", noisy)
    got = taus(dict(fista, calibration=str(tmp_path / "noisy.npz")))
    first = Reconstructor.calibrated(noisy, 2, solver="fista-tv")
    first.measurement(*read_raw(lay.raw(0)))
    own = Reconstructor.calibrated(noisy, 2, solver="fista-tv")
    own.measurement(*read_raw(lay.raw(2)))
    assert got == pytest.approx([first.tau] * 2)
    assert first.tau != pytest.approx(tv_weight("fista-tv", None, 2))
    assert own.tau != pytest.approx(first.tau, rel=1e-6)     # frame 2 alone would differ
