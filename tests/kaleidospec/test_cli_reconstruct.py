"""``kaleidospec reconstruct`` end to end on a tiny 24×24×6 problem, and every bad input."""

import re
import subprocess
import sys

import numpy as np
import pytest
import scipy.io

from kaleidospec.cli import main
from recon.io.arrays import write_array2d
from recon.io.cubes import read_cube, write_cube
from recon.metrics import psnr

H = W = 24
L = 6
STEP = 2
WL = np.linspace(450.0, 650.0, L)


def _truth():
    y, x = np.mgrid[0:H, 0:W] / (H - 1)
    cube = np.empty((H, W, L), np.float32)
    for l in range(L):
        cube[:, :, l] = 0.2 + 0.1 * l / L
        cube[:, :, l] += 0.6 * ((x - 0.4) ** 2 + (y - 0.5) ** 2 < 0.08) * (l + 1) / L
        cube[:, :, l] += 0.4 * ((x > 0.65) & (y < 0.35)) * (L - l) / L
    return cube


@pytest.fixture
def problem(tmp_path):
    from recon.operators import standard_cassi

    rng = np.random.default_rng(0)
    mask = (rng.random((H, W)) < 0.5).astype(np.float32)
    truth = _truth()
    g = standard_cassi(mask, STEP, L).forward(np.ascontiguousarray(np.moveaxis(truth, 2, 0)))[0]
    paths = {
        "meas": write_array2d(tmp_path / "meas.npy", g),
        "mask": write_array2d(tmp_path / "mask.mat", mask, key="mask"),
        "truth": write_cube(tmp_path / "truth.npz", truth, WL),
    }
    return tmp_path, paths, truth


def run(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    out, err = capsys.readouterr()
    return exc.value.code, out, err


def base_args(paths, out):
    return ["reconstruct", "--measurement", str(paths["meas"]), "--mask", str(paths["mask"]),
            "--step", str(STEP), "--out", str(out), "--iters", "15"]


def test_success_writes_cube_and_prints_metrics(problem, capsys):
    tmp, paths, truth = problem
    out = tmp / "rec.npz"
    code, stdout, err = run(base_args(paths, out) + ["--truth", str(paths["truth"])], capsys)
    assert code in (0, None), err
    cube, wl = read_cube(out)
    assert cube.shape == (H, W, L)
    np.testing.assert_allclose(wl, WL)  # inferred from the truth file
    m = re.search(r"PSNR ([\d.]+) dB", stdout)
    assert m, stdout
    assert float(m.group(1)) == pytest.approx(psnr(cube, truth), abs=0.006)
    assert psnr(cube, truth) > psnr(np.zeros_like(truth) + truth.mean(), truth)
    assert "SSIM" in stdout and "SAM" in stdout and re.search(r"in [\d.]+ s", stdout)
    assert err == ""


def _other_solvers():
    from recon.app import solver_names

    return [s for s in solver_names() if s != "gap-tv"]


@pytest.mark.parametrize("solver", _other_solvers())
def test_other_solvers_and_exr_output(problem, capsys, solver):
    tmp, paths, _ = problem
    out = tmp / "rec.exr"
    code, stdout, err = run(base_args(paths, out) + ["--solver", solver, "--bands", str(L),
                                                     "--wavelengths", "450:650:6"], capsys)
    assert code in (0, None), err
    cube, wl = read_cube(out)
    assert cube.shape == (H, W, L) and np.all(np.isfinite(cube))
    np.testing.assert_allclose(wl, WL)
    assert "PSNR" not in stdout


def test_noise_solves_as_run_does(problem, capsys):
    """--noise: the solve of kaleidospec.reconstruct.solve_views (unit row norm, the weights
    from the noise), the same cube as calling it; --tol stops it before --iters."""
    from kaleidospec.reconstruct import solve_views
    from recon.operators import standard_cassi

    tmp, paths, truth = problem
    g = np.load(paths["meas"])
    sigma = 0.005 * float(g.max())
    noisy = write_array2d(tmp / "noisy.npy", (g + np.random.default_rng(1).normal(
        0.0, sigma, g.shape)).astype(np.float32))
    out = tmp / "rec.npz"
    args = base_args(paths, out)[:-2] + ["--measurement", str(noisy), "--solver", "fista-tv",
                                         "--prior", "subspace-tv", "--noise", str(sigma),
                                         "--iters", "400", "--tol", "1e-3"]
    code, stdout, err = run(args, capsys)
    assert code in (0, None), err
    iters = int(re.search(r"(\d+) iterations", stdout).group(1))
    assert iters < 400
    mask = scipy.io.loadmat(paths["mask"])["mask"].astype(np.float32)
    want, info = solve_views(standard_cassi(mask, STEP, L), np.load(noisy), 1,
                             solver="fista-tv", prior="subspace-tv", noise=sigma, iters=400,
                             tol=1e-3)
    np.testing.assert_array_equal(read_cube(out)[0], want)
    assert info["iters"] == iters


def _bad_cases(tmp, paths):
    g = np.load(paths["meas"])
    nan = g.copy()
    nan[2, 3] = np.nan
    write_array2d(tmp / "nan.npy", nan)
    write_array2d(tmp / "short.npy", g[:-1])
    write_array2d(tmp / "narrow.npy", g[:, :-1])  # W + 9: step 2 does not divide 9
    (tmp / "empty.npy").write_bytes(b"")
    (tmp / "garbage.exr").write_bytes(b"not an exr file at all")
    scipy.io.savemat(tmp / "two.mat", {"a": g, "b": g})
    write_cube(tmp / "small_truth.npz", _truth()[:, :, :4], WL[:4])
    np.save(tmp / "mask3d.npy", np.ones((H, W + 1, L), np.float32))
    return {
        "mismatched heights": ["--measurement", str(tmp / "short.npy")],
        "NaN in measurement": ["--measurement", str(tmp / "nan.npy")],
        "empty file": ["--measurement", str(tmp / "empty.npy")],
        "unreadable file": ["--mask", str(tmp / "garbage.exr")],
        "missing file": ["--mask", str(tmp / "nothere.npy")],
        "missing mat key": ["--mask-key", "Phi"],
        "ambiguous mat": ["--measurement", str(tmp / "two.mat")],
        "step does not fit": ["--measurement", str(tmp / "narrow.npy")],
        "bad step": ["--step", "0"],
        "bands disagree": ["--bands", "5"],
        "truth shape": ["--truth", str(tmp / "small_truth.npz")],
        "bad solver": ["--solver", "magic"],
        "bad noise": ["--noise", "0"],
        "NaN noise": ["--noise", "nan"],
        "bad tol": ["--tol", "-1"],
        "bad wavelengths": ["--wavelengths", "450:650:7"],
        "exr without wavelengths": ["--out", str(tmp / "rec.exr")],
        "bad out suffix": ["--out", str(tmp / "rec.txt")],
        "out folder is a file": ["--out", str(tmp / "meas.npy" / "new" / "rec.npz")],
        "3-D mask of another shape": ["--mask", str(tmp / "mask3d.npy")],
    }


def test_bad_inputs_exit_2_with_one_line(problem, capsys):
    tmp, paths, _ = problem
    out = tmp / "rec.npz"
    before = sorted(p.name for p in tmp.iterdir())
    for name, extra in _bad_cases(tmp, paths).items():
        listing = sorted(p.name for p in tmp.iterdir())
        code, stdout, err = run(base_args(paths, out) + extra, capsys)
        assert code == 2, (name, err)
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("kaleidospec: error:"), (name, err)
        assert "Traceback" not in err
        assert sorted(p.name for p in tmp.iterdir()) == listing, name  # nothing written
    assert not out.exists()
    assert set(before) <= {p.name for p in tmp.iterdir()}


@pytest.mark.parametrize("which", ["meas", "mask", "truth"])
def test_output_equal_to_an_input_is_refused(problem, capsys, which):
    tmp, paths, _ = problem
    target = paths[which]
    before = target.read_bytes()
    args = base_args(paths, tmp / "." / target.name) + ["--truth", str(paths["truth"])]
    code, _, err = run(args, capsys)
    assert code == 2 and "input" in err and len(err.strip().splitlines()) == 1
    assert target.read_bytes() == before


def test_subprocess_bad_input_no_traceback(problem):
    tmp, paths, _ = problem
    (tmp / "empty.npy").write_bytes(b"")
    args = base_args(paths, tmp / "rec.npz")
    args[2] = str(tmp / "empty.npy")
    r = subprocess.run([sys.executable, "-m", "kaleidospec.cli", *args], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "empty" in r.stderr
    assert not (tmp / "rec.npz").exists()


def test_help_imports_nothing_heavy():
    code = ("import sys, kaleidospec.cli; "
            "print(sorted(m for m in ('numpy', 'scipy', 'recon', 'OpenEXR', 'colour', 'skimage') "
            "if m in sys.modules))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.stdout.strip() == "[]"


def test_demo_is_the_run_of_the_default_scene(capsys):
    # The demo itself runs in tests/test_readme.py (the README's quick start, as written);
    # here its settings and its refusal of a bad --model.
    from kaleidospec.commands import demo

    # A scene no calibration capture shows (the ColorChecker fits the gains).
    assert demo.DEFAULT_SCENE == "natural" and demo.DEFAULT_MODEL == "footprint"
    code, stdout, err = run(["demo", "--help"], capsys)
    assert code in (0, None) and "--out" in stdout and "--model" in stdout
    code, _, err = run(["demo", "--model", "exact"], capsys)
    assert code == 2 and "--model" in err


# -- output folders and permissions ---------------------------------------------------------
def _umask():
    import os

    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_missing_output_folders_are_created_with_ordinary_permissions(problem, capsys):
    tmp, paths, _ = problem
    out = tmp / "new" / "deeper" / "rec.npz"
    code, stdout, err = run(base_args(paths, out), capsys)
    assert code in (0, None), err
    assert read_cube(out)[0].shape == (H, W, L)
    for d in (tmp / "new", tmp / "new" / "deeper"):
        assert d.stat().st_mode & 0o777 == 0o777 & ~_umask()
    for f in out.parent.iterdir():
        assert f.stat().st_mode & 0o777 == 0o666 & ~_umask(), f


@pytest.mark.skipif(not __import__("os").path.isdir("/proc/self"), reason="needs Linux /proc")
def test_output_folder_that_cannot_be_created(problem, capsys):
    tmp, paths, _ = problem
    code, _, err = run(base_args(paths, "/proc/kaleidospec-new/rec.npz"), capsys)
    assert code == 2 and "cannot write" in err and len(err.strip().splitlines()) == 1


def test_a_failed_write_leaves_no_output_and_no_new_folder(problem, capsys, monkeypatch):
    import recon.report

    tmp, paths, _ = problem
    old = write_cube(tmp / "old" / "rec.npz", np.ones((H, W, L), np.float32), WL) \
        if (tmp / "old").mkdir() is None else None
    before = old.read_bytes()

    def disk_full(*args, **kwargs):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(recon.report, "band_montage", disk_full)
    for out in (tmp / "new" / "rec.npz", old):
        code, _, err = run(base_args(paths, out), capsys)
        assert code == 2 and "No space left" in err and len(err.strip().splitlines()) == 1
    assert not (tmp / "new").exists()
    assert [p.name for p in (tmp / "old").iterdir()] == ["rec.npz"]  # no picture, no temporary
    assert old.read_bytes() == before  # the earlier cube is untouched


# -- pictures -------------------------------------------------------------------------------
def _png(path):
    import imageio.v3 as iio

    return iio.imread(path)


def test_pictures_beside_the_cube(problem, capsys):
    from recon.report import srgb_image

    tmp, paths, truth = problem
    out = tmp / "res" / "rec.npz"
    code, stdout, err = run(base_args(paths, out) + ["--truth", str(paths["truth"])], capsys)
    assert code in (0, None), err
    assert sorted(p.name for p in out.parent.iterdir()) == [
        "rec.npz", "rec_bands.png", "rec_spectra.png", "rec_srgb.png"]
    cube, wl = read_cube(out)
    # The preview is the cube's own sRGB rendering at its wavelengths (those of the truth).
    want = np.round(srgb_image(cube, wl)[0] * 255).astype(np.uint8)
    np.testing.assert_array_equal(_png(out.parent / "rec_srgb.png"), want)
    bands, spectra = _png(out.parent / "rec_bands.png"), _png(out.parent / "rec_spectra.png")
    assert bands.shape[2] in (3, 4) and bands.shape[0] > 100 and bands[..., :3].std() > 10
    assert spectra.shape[0] > 100 and spectra[..., :3].std() > 10
    for name in ("rec_srgb.png", "rec_bands.png", "rec_spectra.png"):
        assert name in stdout
    assert "assumed" not in stdout  # wavelengths known


def test_no_pictures_and_no_spectra_without_truth(problem, capsys):
    tmp, paths, _ = problem
    code, _, err = run(base_args(paths, tmp / "a" / "rec.npz") + ["--no-pictures"], capsys)
    assert code in (0, None), err
    assert [p.name for p in (tmp / "a").iterdir()] == ["rec.npz"]
    code, stdout, err = run(base_args(paths, tmp / "b" / "rec.npz"), capsys)
    assert code in (0, None), err
    assert sorted(p.name for p in (tmp / "b").iterdir()) == ["rec.npz", "rec_bands.png",
                                                             "rec_srgb.png"]
    # No wavelengths anywhere: the pictures say what they assumed (6 bands: evenly spaced).
    assert "assumed 450.0–650.0 nm (evenly spaced)" in stdout


def test_a_picture_may_not_overwrite_an_input(problem, capsys):
    tmp, paths, _ = problem
    (tmp / "rec_srgb.png").symlink_to(paths["meas"])  # a picture's name leads to an input
    before = paths["meas"].read_bytes()
    code, _, err = run(base_args(paths, tmp / "rec.npz"), capsys)
    assert code == 2 and "input" in err and not (tmp / "rec.npz").exists()
    assert paths["meas"].read_bytes() == before


# -- the real-data layouts: TSA-Net / MST files ---------------------------------------------
N28 = 28


@pytest.fixture
def real_layout(tmp_path):
    """A capture laid out like TSA-Net's real data (``scene1.mat`` with ``meas_real``,
    ``mask.mat`` with a 2-D ``mask``, ``mask_3d_shift.mat``), small, 28 bands, step 2."""
    from recon.operators import standard_cassi

    h, w = 20, 16
    rng = np.random.default_rng(4)
    mask = (rng.random((h, w)) < 0.5).astype(np.float32)
    y, x = np.mgrid[0:h, 0:w]
    truth = np.empty((h, w, N28), np.float32)
    for l in range(N28):
        truth[:, :, l] = 0.3 + 0.5 * ((x > 6) & (y < 12)) * (l / N28) + 0.1 * (y > 14)
    g = standard_cassi(mask, STEP, N28).forward(np.ascontiguousarray(np.moveaxis(truth, 2, 0)))[0]
    shifted = np.zeros((h, w + STEP * (N28 - 1), N28), np.float32)
    for l in range(N28):
        shifted[:, STEP * l:STEP * l + w, l] = mask
    # Real files hold other variables too: a second 2-D array beside the measurement.
    scipy.io.savemat(tmp_path / "scene1.mat", {"meas_real": g, "dark": np.full_like(g, 0.01)})
    scipy.io.savemat(tmp_path / "mask.mat", {"mask": mask})
    scipy.io.savemat(tmp_path / "mask_3d_shift.mat", {"mask_3d_shift": shifted})
    scipy.io.savemat(tmp_path / "mask_3d.mat", {"mask_3d": np.repeat(mask[:, :, None], N28, 2)})
    return tmp_path, truth


def _real(tmp, mask, out, *extra):
    return ["reconstruct", "--measurement", str(tmp / "scene1.mat"), "--mask", str(tmp / mask),
            "--step", str(STEP), "--out", str(tmp / out), "--iters", "20", *extra]


def test_shifted_mask_cube_gives_the_2d_masks_reconstruction(real_layout, capsys):
    tmp, truth = real_layout
    cubes = {}
    for mask, key in (("mask.mat", "mask"), ("mask_3d_shift.mat", "mask_3d_shift"),
                      ("mask_3d.mat", "mask_3d")):
        out = f"{key}.npz"
        code, stdout, err = run(_real(tmp, mask, out), capsys)
        assert code in (0, None), err
        first = stdout.splitlines()[0]
        # It says which variables it read: found by name, not by a guess between two arrays.
        assert "scene1.mat['meas_real']" in first and f"{mask}['{key}']" in first, first
        assert f"{N28} bands" in first
        cubes[key], wl = read_cube(tmp / out)
        assert wl is None  # nothing in the inputs says
    assert cubes["mask"].shape == truth.shape
    assert psnr(cubes["mask"], truth) > psnr(np.full_like(truth, truth.mean()), truth) + 3
    np.testing.assert_allclose(cubes["mask_3d_shift"], cubes["mask"], rtol=0, atol=1e-5)
    np.testing.assert_allclose(cubes["mask_3d"], cubes["mask"], rtol=0, atol=1e-5)


def test_standard_28_band_wavelengths_for_the_pictures(real_layout, capsys):
    from recon.io.cubes import CASSI_28_WAVELENGTHS
    from recon.report import srgb_image

    tmp, _ = real_layout
    code, stdout, err = run(_real(tmp, "mask_3d_shift.mat", "rec.npz"), capsys)
    assert code in (0, None), err
    assert "assumed 453.3–648.1 nm (the standard 28 CASSI bands)" in stdout
    cube, _ = read_cube(tmp / "rec.npz")
    want = np.round(srgb_image(cube, np.array(CASSI_28_WAVELENGTHS))[0] * 255).astype(np.uint8)
    np.testing.assert_array_equal(_png(tmp / "rec_srgb.png"), want)
    # Without a truth the montage is a sheet of every band: 4 lines of 7 (1.6 × 1.75 in each).
    assert _png(tmp / "rec_bands.png").shape[:2] == (700, 1120)


def test_key_names_the_measurement(real_layout, capsys):
    tmp, _ = real_layout
    code, stdout, err = run(_real(tmp, "mask.mat", "dark.npz", "--key", "dark", "--no-pictures"),
                            capsys)
    assert code in (0, None), err
    assert "scene1.mat['dark']" in stdout.splitlines()[0]
    assert read_cube(tmp / "dark.npz")[0].max() < 0.1  # the dark frame's cube, not the scene's
    scipy.io.savemat(tmp / "two.mat", {"a": np.ones((20, 70)), "b": np.ones((20, 70))})
    code, _, err = run(_real(tmp, "mask.mat", "x.npz") + ["--measurement", str(tmp / "two.mat")],
                       capsys)
    assert code == 2 and "name one with a key" in err
    code, stdout, err = run(_real(tmp, "mask.mat", "x.npz", "--no-pictures")
                            + ["--measurement", str(tmp / "two.mat"), "--key", "b"], capsys)
    assert code in (0, None), err
    assert "two.mat['b']" in stdout.splitlines()[0]
