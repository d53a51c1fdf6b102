"""``kaleidospec reconstruct`` on bad input: exit status 2, one line on stderr
(``kaleidospec: error: ...``), no traceback, no output (not even a temporary file), and
every input file left byte-for-byte as it was, with its mtime.  One test per case.

Also: a boolean mask file is accepted (0/1), a measurement negative beyond read noise gives
one warning line and still succeeds, one negative on average is refused (see recon.app).
"""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from kaleidospec.cli import main
from recon.io.arrays import write_array2d
from recon.io.cubes import read_cube, write_cube

H = W = 16
L = 4
STEP = 2
WL = np.linspace(450.0, 600.0, L)


def _truth():
    c = np.full((H, W, L), 0.3, np.float32)
    c[4:12, 3:10] = np.linspace(0.5, 1.0, L, dtype=np.float32)
    return c


@pytest.fixture
def setup(tmp_path):
    from recon.operators import standard_cassi

    mask = (np.random.default_rng(0).random((H, W)) < 0.5).astype(np.float32)
    g = standard_cassi(mask, STEP, L).forward(np.ascontiguousarray(np.moveaxis(_truth(), 2, 0)))[0]
    paths = {"meas": write_array2d(tmp_path / "meas.npy", g),
             "mask": write_array2d(tmp_path / "mask.npz", mask, key="mask"),
             "truth": write_cube(tmp_path / "truth.npz", _truth(), WL)}
    return tmp_path, paths, g, mask


def _args(paths, out, **over):
    a = {"--measurement": paths["meas"], "--mask": paths["mask"], "--step": STEP,
         "--out": out, "--iters": 5}
    a.update(over)
    argv = ["reconstruct"]
    for k, v in a.items():
        argv += [k, str(v)]
    return argv


def _state(folder: Path):
    return {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in sorted(folder.rglob("*"))
            if p.is_file() or p.is_symlink()}


def _run(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    out, err = capsys.readouterr()
    return exc.value.code, out, err


def _fails_cleanly(tmp, argv, capsys, expect=None):
    before = _state(tmp)
    names = sorted(p.name for p in tmp.rglob("*"))
    code, out, err = _run(argv, capsys)
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("kaleidospec: error:"), err
    assert "Traceback" not in err + out
    if expect:
        assert expect in lines[0], lines[0]
    assert sorted(p.name for p in tmp.rglob("*")) == names  # nothing new, not even a temp file
    assert _state(tmp) == before  # inputs untouched (bytes and mtime)
    return lines[0]


def _truncated(src: Path, dst: Path, keep=0.5) -> Path:
    dst.write_bytes(src.read_bytes()[: int(src.stat().st_size * keep)])
    return dst


# -- corrupt or truncated files ------------------------------------------------------------
def test_truncated_npy_measurement(setup, capsys):
    tmp, p, _, _ = setup
    bad = _truncated(p["meas"], tmp / "t.npy")
    _fails_cleanly(tmp, _args(p, tmp / "rec.npz", **{"--measurement": bad}), capsys, "t.npy")


def test_truncated_npz_mask(setup, capsys):
    tmp, p, _, _ = setup
    bad = _truncated(p["mask"], tmp / "t.npz")
    _fails_cleanly(tmp, _args(p, tmp / "rec.npz", **{"--mask": bad}), capsys, "t.npz")


def test_corrupt_npz_mask(setup, capsys):
    tmp, p, _, _ = setup
    (tmp / "c.npz").write_bytes(b"PK\x03\x04" + os.urandom(300))
    _fails_cleanly(tmp, _args(p, tmp / "rec.npz", **{"--mask": tmp / "c.npz"}), capsys)


def test_truncated_exr_measurement(setup, capsys):
    tmp, p, g, _ = setup
    write_array2d(tmp / "g.exr", g)
    bad = _truncated(tmp / "g.exr", tmp / "t.exr")
    _fails_cleanly(tmp, _args(p, tmp / "rec.npz", **{"--measurement": bad}), capsys, "OpenEXR")


def test_corrupt_mat_mask(setup, capsys):
    tmp, p, _, mask = setup
    scipy.io.savemat(tmp / "m.mat", {"mask": mask})
    bad = _truncated(tmp / "m.mat", tmp / "t.mat", 0.4)
    _fails_cleanly(tmp, _args(p, tmp / "rec.npz", **{"--mask": bad}), capsys, "t.mat")


def test_truncated_truth_cube(setup, capsys):
    tmp, p, _, _ = setup
    bad = _truncated(p["truth"], tmp / "tt.npz")
    _fails_cleanly(tmp, _args(p, tmp / "rec.npz", **{"--truth": bad}), capsys, "tt.npz")


# -- dtypes --------------------------------------------------------------------------------
def test_complex_measurement(setup, capsys):
    tmp, p, g, _ = setup
    np.save(tmp / "c.npy", g.astype(np.complex64))
    _fails_cleanly(tmp, _args(p, tmp / "rec.npz", **{"--measurement": tmp / "c.npy"}), capsys,
                   "complex")


def test_object_measurement(setup, capsys):
    tmp, p, _, _ = setup
    np.save(tmp / "o.npy", np.array([[1, "x"], [None, 2]], dtype=object), allow_pickle=True)
    _fails_cleanly(tmp, _args(p, tmp / "rec.npz", **{"--measurement": tmp / "o.npy"}), capsys,
                   "pickled")


def test_string_mask(setup, capsys):
    tmp, p, _, _ = setup
    np.save(tmp / "s.npy", np.full((H, W), "ab"))
    _fails_cleanly(tmp, _args(p, tmp / "rec.npz", **{"--mask": tmp / "s.npy"}), capsys, "dtype")


def test_bool_measurement(setup, capsys):
    tmp, p, g, _ = setup
    np.save(tmp / "b.npy", g > 0.5)
    _fails_cleanly(tmp, _args(p, tmp / "rec.npz", **{"--measurement": tmp / "b.npy"}), capsys,
                   "bool")


def test_bool_mask_is_accepted(setup, capsys):
    tmp, p, _, mask = setup
    np.save(tmp / "bm.npy", mask > 0)
    code, _, err = _run(_args(p, tmp / "a.npz", **{"--mask": tmp / "bm.npy"}), capsys)
    assert code in (0, None), err
    code, _, err = _run(_args(p, tmp / "b.npz"), capsys)
    assert code in (0, None), err
    assert np.array_equal(read_cube(tmp / "a.npz")[0], read_cube(tmp / "b.npz")[0])


# -- NaN / Inf / negative ------------------------------------------------------------------
def test_nan_measurement(setup, capsys):
    tmp, p, g, _ = setup
    g = g.copy()
    g[3, 3] = np.nan
    np.save(tmp / "n.npy", g)
    _fails_cleanly(tmp, _args(p, tmp / "rec.npz", **{"--measurement": tmp / "n.npy"}), capsys, "NaN")


def test_inf_mask(setup, capsys):
    tmp, p, _, mask = setup
    m = mask.copy()
    m[0, 0] = np.inf
    np.save(tmp / "i.npy", m)
    _fails_cleanly(tmp, _args(p, tmp / "rec.npz", **{"--mask": tmp / "i.npy"}), capsys, "Inf")


def test_measurement_negative_on_average(setup, capsys):
    tmp, p, g, _ = setup
    np.save(tmp / "neg.npy", -g)
    _fails_cleanly(tmp, _args(p, tmp / "rec.npz", **{"--measurement": tmp / "neg.npy"}), capsys,
                   "not an intensity")


def test_measurement_negative_beyond_noise_warns_once_and_succeeds(setup, capsys):
    tmp, p, g, _ = setup
    g = g.copy()
    g[0, :4] = -0.5 * g.max()
    np.save(tmp / "neg.npy", g)
    code, out, err = _run(_args(p, tmp / "rec.npz", **{"--measurement": tmp / "neg.npy"}), capsys)
    assert code in (0, None), err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("kaleidospec: warning:"), err
    assert (tmp / "rec.npz").exists()


def test_all_closed_mask(setup, capsys):
    tmp, p, _, _ = setup
    np.save(tmp / "z.npy", np.zeros((H, W), np.float32))
    _fails_cleanly(tmp, _args(p, tmp / "rec.npz", **{"--mask": tmp / "z.npy"}), capsys,
                   "operator is zero")


# -- shapes --------------------------------------------------------------------------------
def test_3d_measurement(setup, capsys):
    tmp, p, g, _ = setup
    np.save(tmp / "g3.npy", np.stack([g, g]))
    _fails_cleanly(tmp, _args(p, tmp / "rec.npz", **{"--measurement": tmp / "g3.npy"}), capsys,
                   "3-D")


def test_measurement_narrower_than_mask(setup, capsys):
    tmp, p, g, _ = setup
    np.save(tmp / "narrow.npy", g[:, : W - 3])
    _fails_cleanly(tmp, _args(p, tmp / "rec.npz", **{"--measurement": tmp / "narrow.npy"}), capsys,
                   "narrower")


def test_truth_with_wrong_bands(setup, capsys):
    tmp, p, _, _ = setup
    write_cube(tmp / "t3.npz", _truth()[:, :, :3], WL[:3])
    _fails_cleanly(tmp, _args(p, tmp / "rec.npz", **{"--truth": tmp / "t3.npz"}), capsys, "truth")


def test_iters_zero(setup, capsys):
    tmp, p, _, _ = setup
    _fails_cleanly(tmp, _args(p, tmp / "rec.npz", **{"--iters": 0}), capsys, "--iters")


def test_negative_tau(setup, capsys):
    tmp, p, _, _ = setup
    _fails_cleanly(tmp, _args(p, tmp / "rec.npz", **{"--tau": -1}), capsys, "tau")


# -- outputs -------------------------------------------------------------------------------
def test_output_under_a_regular_file(setup, capsys):
    tmp, p, _, _ = setup
    (tmp / "file.txt").write_text("x")
    _fails_cleanly(tmp, _args(p, tmp / "file.txt" / "rec.npz"), capsys, "not a folder")


def test_output_below_a_regular_file_deeper(setup, capsys):
    tmp, p, _, _ = setup
    (tmp / "file.txt").write_text("x")
    _fails_cleanly(tmp, _args(p, tmp / "file.txt" / "a" / "b" / "rec.npz"), capsys, "not a folder")


def test_missing_output_folders_are_created(setup, capsys):
    # Like `mkdir -p`: a fresh clone has no out/ (it is git-ignored), and the README's first
    # command writes into it.
    tmp, p, _, _ = setup
    code, _, err = _run(_args(p, tmp / "no" / "such" / "rec.npz"), capsys)
    assert code in (0, None), err
    assert (tmp / "no" / "such" / "rec.npz").is_file()


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux /proc")
def test_output_folder_cannot_be_created(setup, capsys):
    tmp, p, _, _ = setup
    _fails_cleanly(tmp, _args(p, Path("/proc/h6_cli_dir/rec.npz")), capsys, "cannot write")


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux /proc")
def test_output_folder_refuses_files(setup, capsys):
    tmp, p, _, _ = setup
    _fails_cleanly(tmp, _args(p, Path("/proc/h6_cli_rec.npz")), capsys, "cannot write")


def test_output_is_an_existing_folder(setup, capsys):
    tmp, p, _, _ = setup
    (tmp / "d.npz").mkdir()
    _fails_cleanly(tmp, _args(p, tmp / "d.npz"), capsys, "folder")


@pytest.mark.parametrize("which", ["meas", "mask", "truth"])
def test_output_equal_to_an_input(setup, capsys, which):
    tmp, p, _, _ = setup
    out = tmp / "x" / ".." / p[which].name
    (tmp / "x").mkdir()
    _fails_cleanly(tmp, _args(p, out, **{"--truth": p["truth"]}), capsys, "input")


def test_output_is_a_symlink_to_an_input(setup, capsys):
    tmp, p, _, _ = setup
    (tmp / "link.npz").symlink_to(p["truth"])
    _fails_cleanly(tmp, _args(p, tmp / "link.npz", **{"--truth": p["truth"]}), capsys, "input")


def test_subprocess_truncated_input_no_traceback(setup):
    tmp, p, _, _ = setup
    bad = _truncated(p["meas"], tmp / "t.npy")
    before = _state(tmp)
    argv = _args(p, tmp / "rec.npz", **{"--measurement": bad})
    r = subprocess.run([sys.executable, "-m", "kaleidospec.cli", *argv], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 2
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    assert _state(tmp) == before
