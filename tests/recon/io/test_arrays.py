"""2-D arrays (measurements, masks): round trips and every bad input."""

import numpy as np
import pytest
import scipy.io

from recon.errors import InputError
from recon.io.arrays import read_array, read_array2d, write_array2d, write_exr


@pytest.fixture
def arr():
    return np.random.default_rng(0).random((7, 11)).astype(np.float32)


@pytest.mark.parametrize("name,version", [("a.npy", "5"), ("a.npz", "5"), ("a.mat", "5"),
                                          ("a.mat", "7.3"), ("a.exr", "5")])
def test_round_trip(tmp_path, arr, name, version):
    p = write_array2d(tmp_path / name, arr, mat_version=version)
    back = read_array2d(p)
    assert back.dtype == np.float32 and back.flags.c_contiguous
    np.testing.assert_array_equal(back, arr)
    assert [q.name for q in tmp_path.iterdir()] == [name]


def test_mat_key_or_single_2d(tmp_path, arr):
    # An MST-style file: the measurement with a 3-D cube and a scalar next to it.
    scipy.io.savemat(tmp_path / "m.mat", {"meas": arr.astype(np.float64), "truth": np.ones((7, 11, 3)),
                                          "step": 2})
    np.testing.assert_allclose(read_array2d(tmp_path / "m.mat"), arr)
    scipy.io.savemat(tmp_path / "two.mat", {"mask": arr, "meas": arr * 2})
    with pytest.raises(InputError, match="more than one"):
        read_array2d(tmp_path / "two.mat")
    np.testing.assert_allclose(read_array2d(tmp_path / "two.mat", key="meas"), arr * 2)
    with pytest.raises(InputError, match="no variable 'Phi'"):
        read_array2d(tmp_path / "two.mat", key="Phi")
    scipy.io.savemat(tmp_path / "none.mat", {"cube": np.ones((2, 2, 2))})
    with pytest.raises(InputError, match="no array candidate"):
        read_array2d(tmp_path / "none.mat")


def test_integer_mask_is_accepted(tmp_path):
    m = (np.random.default_rng(1).random((5, 5)) > 0.5).astype(np.uint8)
    scipy.io.savemat(tmp_path / "mask.mat", {"mask": m})
    np.testing.assert_array_equal(read_array2d(tmp_path / "mask.mat"), m.astype(np.float32))


def test_exr_channels(tmp_path, arr):
    write_exr(tmp_path / "two.exr", {"Y": arr, "Z": arr * 3})
    with pytest.raises(InputError, match="2 channels"):
        read_array2d(tmp_path / "two.exr")
    np.testing.assert_array_equal(read_array2d(tmp_path / "two.exr", key="Z"), arr * 3)
    with pytest.raises(InputError, match="no channel"):
        read_array2d(tmp_path / "two.exr", key="R")


def test_exr_threads_write_the_same_bytes(tmp_path, monkeypatch):
    # The OpenEXR library's thread pool is sized to the process's CPUs on first use, unless
    # it was sized already; its threads compress the line blocks to the same bytes as none.
    import OpenEXR

    from recon.io import arrays

    chans = {f"b{l}": np.random.default_rng(l).random((70, 90)).astype(np.float32)
             for l in range(5)}
    monkeypatch.setattr(arrays, "_openexr", lambda: OpenEXR)  # as the library is now
    saved = OpenEXR.global_thread_count()
    try:
        OpenEXR.set_global_thread_count(0)
        write_exr(tmp_path / "none.exr", chans)
        OpenEXR.set_global_thread_count(3)
        write_exr(tmp_path / "three.exr", chans)
        assert (tmp_path / "none.exr").read_bytes() == (tmp_path / "three.exr").read_bytes()
        monkeypatch.undo()
        arrays._openexr()
        assert OpenEXR.global_thread_count() == 3
        OpenEXR.set_global_thread_count(0)
        monkeypatch.setattr("recon.kernels.cores", lambda: 2)
        arrays._openexr()
        assert OpenEXR.global_thread_count() == 2
    finally:
        OpenEXR.set_global_thread_count(saved)


def test_half_exr(tmp_path, arr):
    import OpenEXR

    OpenEXR.File({}, {"Y": arr.astype(np.float16)}).write(str(tmp_path / "h.exr"))
    np.testing.assert_allclose(read_array2d(tmp_path / "h.exr"), arr, atol=1e-3)


@pytest.mark.parametrize("ext", [".npy", ".npz", ".mat", ".exr"])
def test_missing_empty_truncated(tmp_path, arr, ext):
    p = tmp_path / f"a{ext}"
    with pytest.raises(InputError, match="no such file"):
        read_array2d(p)
    p.write_bytes(b"")
    with pytest.raises(InputError, match="empty"):
        read_array2d(p)
    write_array2d(p, np.random.default_rng(2).random((64, 64)))
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError) as err:
        read_array2d(p)
    assert str(p) in str(err.value) and "\n" not in str(err.value)


def test_truncated_exr_prints_nothing(tmp_path, capfd):
    p = tmp_path / "a.exr"
    write_array2d(p, np.random.default_rng(3).random((64, 64)))
    p.write_bytes(p.read_bytes()[:400])
    with pytest.raises(InputError):
        read_array2d(p)
    out, err = capfd.readouterr()
    assert out == "" and err == ""  # the OpenEXR library's own diagnostics are silenced


def test_bad_values_and_shapes(tmp_path, arr):
    bad = arr.copy()
    bad[3, 4] = np.nan
    np.save(tmp_path / "nan.npy", bad)
    with pytest.raises(InputError, match="nan.npy: measurement contains NaN"):
        read_array2d(tmp_path / "nan.npy", what="measurement")
    bad[3, 4] = -np.inf
    write_exr(tmp_path / "inf.exr", {"Y": bad})
    with pytest.raises(InputError, match="NaN or Inf"):
        read_array2d(tmp_path / "inf.exr")
    np.save(tmp_path / "big.npy", np.array([[1e300, 0.0]]))  # overflows float32
    with pytest.raises(InputError, match="beyond float32"):
        read_array2d(tmp_path / "big.npy")
    np.save(tmp_path / "3d.npy", np.ones((2, 3, 4)))
    with pytest.raises(InputError, match="3-D"):
        read_array2d(tmp_path / "3d.npy")
    np.save(tmp_path / "1d.npy", np.ones(4))
    with pytest.raises(InputError, match="1-D"):
        read_array2d(tmp_path / "1d.npy")
    np.save(tmp_path / "zero.npy", np.ones((0, 4)))
    with pytest.raises(InputError, match="empty"):
        read_array2d(tmp_path / "zero.npy")
    np.save(tmp_path / "str.npy", np.array([["a", "b"]]))
    with pytest.raises(InputError, match="dtype"):
        read_array2d(tmp_path / "str.npy")
    (tmp_path / "a.png").write_bytes(b"x")
    with pytest.raises(InputError, match="unsupported"):
        read_array2d(tmp_path / "a.png")
    with pytest.raises(InputError, match="folder"):
        read_array2d(tmp_path)


def test_read_array_3d_for_multiview(tmp_path):
    g = np.random.default_rng(4).random((3, 5, 8)).astype(np.float32)
    np.save(tmp_path / "g.npy", g)
    np.testing.assert_array_equal(read_array(tmp_path / "g.npy", ndim=(2, 3)), g)


def test_write_refuses_input_and_bad_shape(tmp_path, arr):
    p = write_array2d(tmp_path / "a.npy", arr)
    with pytest.raises(InputError, match="input"):
        write_array2d(p, arr * 0, protect=[p])
    np.testing.assert_array_equal(np.load(p), arr)
    with pytest.raises(InputError, match="2-D"):
        write_array2d(tmp_path / "b.npy", arr[None])
    assert not (tmp_path / "b.npy").exists()


def test_named_array_prefers_the_cassi_keys(tmp_path, arr):
    from recon.io.arrays import MASK_KEYS, MEASUREMENT_KEYS, read_named_array

    # TSA-Net's real captures: meas_real beside other 2-D arrays; no key needed.
    scipy.io.savemat(tmp_path / "scene1.mat", {"aux": arr * 3, "meas_real": arr})
    got, name = read_named_array(tmp_path / "scene1.mat", preferred=MEASUREMENT_KEYS)
    assert name == "meas_real"
    np.testing.assert_allclose(got, arr)
    got, name = read_named_array(tmp_path / "scene1.mat", key="aux", preferred=MEASUREMENT_KEYS)
    assert name == "aux"
    np.testing.assert_allclose(got, arr * 3)
    # A mask file with the shifted cube and the plain mask: the cube is the calibrated one.
    cube = np.stack([arr] * 3, axis=2)
    np.savez(tmp_path / "m.npz", mask=arr, mask_3d_shift=cube)
    got, name = read_named_array(tmp_path / "m.npz", ndim=(2, 3), preferred=MASK_KEYS)
    assert name == "mask_3d_shift" and got.shape == cube.shape
    # The only 2-D array when no name matches; None for a .npy (one array, no name).
    scipy.io.savemat(tmp_path / "one.mat", {"frame": arr, "cube": cube})
    assert read_named_array(tmp_path / "one.mat", preferred=MEASUREMENT_KEYS)[1] == "frame"
    np.save(tmp_path / "a.npy", arr)
    assert read_named_array(tmp_path / "a.npy")[1] is None
    write_exr(tmp_path / "y.exr", {"Y": arr})
    assert read_named_array(tmp_path / "y.exr")[1] == "Y"
