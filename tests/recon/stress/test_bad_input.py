"""Bad input through the Python API: one clear InputError per case, no partial output, no
input touched.

Decisions (documented in the modules):

- bool: a binary *mask* may be bool (True = open; ``reconstruct_standard`` and
  ``read_array2d(..., allow_bool=True)``); a bool measurement or cube is an error.
- negative measurements (:mod:`recon.app`): down to -10 % of the peak they are read noise and
  accepted; further below zero a ``NegativeMeasurementWarning``; negative values with a mean
  that is not positive are not an intensity: InputError.
- outputs: never an input, into an existing folder that accepts files, checked up front by
  ``recon.io.atomic.check_output``; otherwise InputError and nothing written.
"""

import os
import warnings
from pathlib import Path

import numpy as np
import pytest
import scipy.io

from recon.app import NegativeMeasurementWarning, reconstruct, reconstruct_standard
from recon.errors import InputError
from recon.io.arrays import read_array2d, save_mat, write_array2d
from recon.io.atomic import check_output
from recon.io.cubes import read_cube, write_cube
from recon.io.raw import read_raw, write_raw
from recon.operators import standard_cassi

H = W = 12
L = 4
STEP = 1
WL = np.linspace(450.0, 600.0, L)


def _mask():
    return (np.random.default_rng(0).random((H, W)) < 0.5).astype(np.float32)


def _cube():
    x = np.full((H, W, L), 0.3, np.float32)
    x[3:9, 2:8] = 0.9
    return x


def _meas():
    op = standard_cassi(_mask(), STEP, L)
    return op.forward(np.ascontiguousarray(np.moveaxis(_cube(), 2, 0)))[0]


def _state(folder: Path):
    """Every file under ``folder`` with its bytes and mtime."""
    return {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in sorted(folder.rglob("*"))
            if p.is_file()}


@pytest.fixture
def files(tmp_path):
    paths = {
        "cube_exr": write_cube(tmp_path / "cube.exr", _cube(), WL),
        "cube_npz": write_cube(tmp_path / "cube.npz", _cube(), WL),
        "cube_mat": write_cube(tmp_path / "cube.mat", _cube(), WL),
        "cube_mat73": write_cube(tmp_path / "cube73.mat", _cube(), WL, mat_version="7.3"),
        "meas_npy": write_array2d(tmp_path / "meas.npy", _meas()),
        "raw": write_raw(tmp_path / "frame.exr", _meas(), {"seed": 1})[0],
    }
    return tmp_path, paths


def _raises_cleanly(tmp, fn, match=None):
    """fn() raises one InputError (one line), and leaves every file as it was."""
    before = _state(tmp)
    with pytest.raises(InputError, match=match) as exc:
        fn()
    msg = str(exc.value)
    assert msg and "\n" not in msg
    assert _state(tmp) == before
    return msg


def _truncate(src: Path, dst: Path, keep: float = 0.5) -> Path:
    data = src.read_bytes()
    dst.write_bytes(data[: int(len(data) * keep)])
    return dst


# -- corrupt or truncated files ------------------------------------------------------------
def test_truncated_exr(files):
    tmp, p = files
    bad = _truncate(p["cube_exr"], tmp / "trunc.exr")
    assert "OpenEXR" in _raises_cleanly(tmp, lambda: read_cube(bad))


def test_corrupt_exr_header(files):
    tmp, p = files
    data = bytearray(p["cube_exr"].read_bytes())
    data[8:64] = os.urandom(56)  # keep the magic number, scramble the header
    bad = tmp / "corrupt.exr"
    bad.write_bytes(bytes(data))
    _raises_cleanly(tmp, lambda: read_cube(bad))


def test_truncated_raw_frame(files):
    tmp, p = files
    bad = _truncate(p["raw"], tmp / "rawtrunc.exr")
    (tmp / "rawtrunc.json").write_text("{}")
    _raises_cleanly(tmp, lambda: read_raw(bad))


def test_truncated_npz(files):
    tmp, p = files
    bad = _truncate(p["cube_npz"], tmp / "trunc.npz")
    assert ".npz" in _raises_cleanly(tmp, lambda: read_cube(bad))


def test_corrupt_npz(files):
    tmp, _ = files
    bad = tmp / "corrupt.npz"
    bad.write_bytes(b"PK\x03\x04" + os.urandom(200))
    _raises_cleanly(tmp, lambda: read_cube(bad))


def test_truncated_npy(files):
    tmp, p = files
    bad = _truncate(p["meas_npy"], tmp / "trunc.npy")
    _raises_cleanly(tmp, lambda: read_array2d(bad))


def test_truncated_mat_v5(files):
    tmp, p = files
    bad = _truncate(p["cube_mat"], tmp / "trunc.mat", 0.6)
    _raises_cleanly(tmp, lambda: read_cube(bad))


def test_truncated_mat_v73(files):
    tmp, p = files
    bad = _truncate(p["cube_mat73"], tmp / "trunc73.mat", 0.6)
    _raises_cleanly(tmp, lambda: read_cube(bad))


def test_empty_file(files):
    tmp, _ = files
    (tmp / "empty.npz").write_bytes(b"")
    assert "empty" in _raises_cleanly(tmp, lambda: read_cube(tmp / "empty.npz"))


def test_folder_given_as_a_file(files):
    tmp, _ = files
    (tmp / "dir.npy").mkdir()
    assert "folder" in _raises_cleanly(tmp, lambda: read_array2d(tmp / "dir.npy"))


# -- dtypes --------------------------------------------------------------------------------
def test_complex_array_file(files):
    tmp, _ = files
    np.save(tmp / "c.npy", _meas().astype(np.complex64))
    assert "complex" in _raises_cleanly(tmp, lambda: read_array2d(tmp / "c.npy"))


def test_object_array_file_is_refused_without_unpickling(files):
    tmp, _ = files
    arr = np.empty((2, 2), dtype=object)
    arr[:] = [[1, "a"], [None, 2.0]]
    np.save(tmp / "o.npy", arr, allow_pickle=True)
    assert "pickled" in _raises_cleanly(tmp, lambda: read_array2d(tmp / "o.npy"))


def test_string_array_file(files):
    tmp, _ = files
    np.save(tmp / "s.npy", np.array([["a", "b"], ["c", "d"]]))
    _raises_cleanly(tmp, lambda: read_array2d(tmp / "s.npy"), match="dtype")


def test_bool_measurement_file_is_refused(files):
    tmp, _ = files
    np.save(tmp / "b.npy", _meas() > 0.5)
    _raises_cleanly(tmp, lambda: read_array2d(tmp / "b.npy", what="measurement"), match="bool")


def test_bool_mask_file_is_accepted_as_0_1(files):
    tmp, _ = files
    np.save(tmp / "bm.npy", _mask() > 0)
    m = read_array2d(tmp / "bm.npy", what="mask", allow_bool=True)
    assert m.dtype == np.float32 and np.array_equal(m, _mask())


@pytest.mark.parametrize("dtype", [np.complex64, object, "U3", bool])
def test_bad_dtype_measurement_in_api(dtype):
    g = _meas().astype(dtype) if dtype is not object else _meas().astype(object)
    with pytest.raises(InputError, match="dtype"):
        reconstruct_standard(g, _mask(), STEP, iters=2)


@pytest.mark.parametrize("dtype", [np.complex64, object, "U3"])
def test_bad_dtype_mask_in_api(dtype):
    with pytest.raises(InputError, match="dtype"):
        reconstruct_standard(_meas(), _mask().astype(dtype), STEP, iters=2)


def test_bool_mask_in_api_is_accepted():
    a, _ = reconstruct_standard(_meas(), _mask() > 0, STEP, iters=3)
    b, _ = reconstruct_standard(_meas(), _mask(), STEP, iters=3)
    assert np.array_equal(a, b)


# -- NaN / Inf -----------------------------------------------------------------------------
def test_nan_in_measurement_file(files):
    tmp, _ = files
    g = _meas()
    g[1, 1] = np.nan
    np.save(tmp / "nan.npy", g)
    assert "NaN" in _raises_cleanly(tmp, lambda: read_array2d(tmp / "nan.npy"))


def test_inf_in_cube_file(files):
    tmp, _ = files
    c = _cube()
    c[0, 0, 0] = np.inf
    np.savez(tmp / "inf.npz", cube=c)
    _raises_cleanly(tmp, lambda: read_cube(tmp / "inf.npz"), match="NaN or Inf")


def test_float64_beyond_float32_range(files):
    tmp, _ = files
    g = _meas().astype(np.float64)
    g[0, 0] = 1e300
    np.save(tmp / "huge.npy", g)
    _raises_cleanly(tmp, lambda: read_array2d(tmp / "huge.npy"), match="float32")


@pytest.mark.parametrize("what", ["measurement", "mask", "x0", "truth"])
def test_nan_in_api_arrays(what):
    g, m, x0, truth = _meas(), _mask(), _cube(), _cube()
    {"measurement": g, "mask": m, "x0": x0, "truth": truth}[what][0, 0] = np.nan
    with pytest.raises(InputError, match=r"NaN|non-finite"):
        reconstruct_standard(g, m, STEP, iters=2, x0=x0, truth=truth)


# -- negative values -----------------------------------------------------------------------
def test_read_noise_negatives_are_accepted_silently():
    g = _meas() + np.random.default_rng(0).normal(0, 0.01 * _meas().max(), _meas().shape)
    assert g.min() < 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cube, _ = reconstruct_standard(g.astype(np.float32), _mask(), STEP, iters=3)
    assert np.all(np.isfinite(cube))


def test_negatives_beyond_noise_warn():
    g = _meas()
    g[0, :3] = -0.3 * g.max()
    with pytest.warns(NegativeMeasurementWarning, match="beyond read noise"):
        cube, _ = reconstruct_standard(g, _mask(), STEP, iters=3)
    assert np.all(np.isfinite(cube))


def test_measurement_that_is_not_an_intensity_is_an_error():
    with pytest.raises(InputError, match="not an intensity"):
        reconstruct_standard(-_meas(), _mask(), STEP, iters=3)
    with pytest.raises(InputError, match="not an intensity"):
        reconstruct_standard(_meas() - _meas().mean() - 1e-3, _mask(), STEP, iters=3)


# -- shapes --------------------------------------------------------------------------------
def test_3d_measurement_file(files):
    tmp, _ = files
    np.save(tmp / "m3.npy", np.ones((2, H, W), np.float32))
    _raises_cleanly(tmp, lambda: read_array2d(tmp / "m3.npy"), match="3-D")


def test_wrong_measurement_shape_in_api():
    op = standard_cassi(_mask(), STEP, L)
    with pytest.raises(InputError, match="shape"):
        reconstruct(_meas()[:, :-1], op, iters=2)


def test_step_does_not_fit_widths():
    with pytest.raises(InputError, match="step"):
        reconstruct_standard(_meas(), _mask(), 2, iters=2)


@pytest.mark.parametrize("what", ["x0", "truth"])
def test_wrong_cube_shape_in_api(what):
    bad = _cube()[:, :, :-1]
    with pytest.raises(InputError, match=what):
        reconstruct_standard(_meas(), _mask(), STEP, iters=2, **{what: bad})


def test_1d_mask_in_api():
    with pytest.raises(InputError, match="2-D"):
        reconstruct_standard(_meas(), _mask()[0], STEP, iters=2)


# -- outputs -------------------------------------------------------------------------------
def test_output_under_a_regular_file(files):
    tmp, _ = files
    (tmp / "plain.txt").write_text("x")
    out = tmp / "plain.txt" / "rec.npz"
    msg = _raises_cleanly(tmp, lambda: write_cube(out, _cube(), WL))
    assert "not a folder" in msg
    _raises_cleanly(tmp, lambda: check_output(out))


def test_output_folder_missing(files):
    tmp, _ = files
    out = tmp / "nope" / "rec.npz"
    assert "does not exist" in _raises_cleanly(tmp, lambda: write_cube(out, _cube(), WL))


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux /proc")
def test_output_in_a_folder_that_refuses_files():
    # /proc refuses new files even to root (tests run as root, so permission bits cannot be
    # used to make a folder unwritable).
    out = Path("/proc/h6_stress_rec.npz")
    with pytest.raises(InputError, match="cannot write"):
        check_output(out)
    with pytest.raises(InputError, match="cannot write"):
        write_cube(out, _cube(), WL)
    assert not out.exists()


def test_output_is_a_folder(files):
    tmp, _ = files
    (tmp / "isdir.npz").mkdir()
    _raises_cleanly(tmp, lambda: write_cube(tmp / "isdir.npz", _cube(), WL), match="folder")


@pytest.mark.parametrize("alias", ["same", "dotted", "symlink"])
def test_output_equal_to_an_input(files, alias):
    tmp, p = files
    src = p["cube_npz"]
    if alias == "same":
        out = src
    elif alias == "dotted":
        out = tmp / "sub" / ".." / src.name
        (tmp / "sub").mkdir()
    else:
        out = tmp / "link.npz"
        out.symlink_to(src)
    msg = _raises_cleanly(tmp, lambda: write_cube(out, _cube() * 2, WL, protect=(src,)))
    assert "input" in msg
    _raises_cleanly(tmp, lambda: check_output(out, (src,)))


def test_failed_write_leaves_no_partial_file(files, monkeypatch):
    tmp, _ = files
    before = _state(tmp)

    def boom(path, *a, **k):
        Path(path).write_bytes(b"partial")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(np, "savez_compressed", boom)
    with pytest.raises(OSError):
        write_cube(tmp / "new.npz", _cube(), WL)
    assert _state(tmp) == before and not any(tmp.glob(".new.npz*"))


def test_save_mat_bad_version_writes_nothing(files):
    tmp, _ = files
    _raises_cleanly(tmp, lambda: save_mat(tmp / "x.mat", {"a": np.ones((2, 2))}, version="9"))


def test_ambiguous_mat_needs_a_key(files):
    tmp, _ = files
    scipy.io.savemat(tmp / "two.mat", {"a": _meas(), "b": _meas()})
    _raises_cleanly(tmp, lambda: read_array2d(tmp / "two.mat"), match="key")
