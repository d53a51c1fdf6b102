"""Cube files: round trips in every format, every bad input, atomic writes."""

import os

import h5py
import numpy as np
import pytest
import scipy.io

from recon.errors import InputError
from recon.io import atomic
from recon.io.cubes import exr_channel_name, parse_exr_channel, read_cube, write_cube

WL = np.array([450.0, 461.5, 475.25, 490.0, 512.0])


@pytest.fixture
def cube():
    rng = np.random.default_rng(0)
    return rng.random((6, 9, WL.size)).astype(np.float32)


def _leftovers(folder):
    return [p.name for p in folder.iterdir() if p.name.startswith(".")]


@pytest.mark.parametrize("name", ["c.exr", "c.npz", "c.mat"])
def test_round_trip_with_wavelengths(tmp_path, cube, name):
    p = write_cube(tmp_path / name, cube, WL)
    back, wl = read_cube(p)
    assert back.dtype == np.float32 and back.shape == cube.shape
    np.testing.assert_array_equal(back, cube)
    np.testing.assert_allclose(wl, WL, rtol=0, atol=1e-9)
    assert _leftovers(tmp_path) == []


def test_round_trip_npy_has_no_wavelengths(tmp_path, cube):
    write_cube(tmp_path / "c.npy", cube)
    back, wl = read_cube(tmp_path / "c.npy")
    np.testing.assert_array_equal(back, cube)
    assert wl is None
    _, wl = read_cube(tmp_path / "c.npy", wavelengths=WL)
    np.testing.assert_array_equal(wl, WL)


def test_npz_without_wavelengths(tmp_path, cube):
    write_cube(tmp_path / "c.npz", cube)
    with np.load(tmp_path / "c.npz") as z:
        assert sorted(z.files) == ["cube"]
    assert read_cube(tmp_path / "c.npz")[1] is None


def test_exr_layout(tmp_path, cube):
    import OpenEXR

    write_cube(tmp_path / "c.exr", cube, WL)
    f = OpenEXR.File(str(tmp_path / "c.exr"), separate_channels=True)
    assert set(f.channels()) == {exr_channel_name(w) for w in WL}
    assert "S0.461,500000nm" in f.channels()
    np.testing.assert_allclose(f.header()["wavelengths"], WL)
    np.testing.assert_array_equal(f.channels()["S0.475,250000nm"].pixels, cube[:, :, 2])
    assert parse_exr_channel("S0.461,500000nm") == 461.5
    assert parse_exr_channel("R") is None


def test_mat_v5_uses_img_key(tmp_path, cube):
    write_cube(tmp_path / "c.mat", cube, WL)
    d = scipy.io.loadmat(tmp_path / "c.mat")
    assert d["img"].shape == cube.shape
    # MST-style files with other keys: pick by name, or the single 3-D array.
    scipy.io.savemat(tmp_path / "kaist.mat", {"img_expand": cube.astype(np.float64)})
    np.testing.assert_allclose(read_cube(tmp_path / "kaist.mat")[0], cube)
    scipy.io.savemat(tmp_path / "two.mat", {"a": cube, "b": cube * 2})
    np.testing.assert_allclose(read_cube(tmp_path / "two.mat", key="b")[0], cube * 2)


def test_mat_v73_transposed_storage(tmp_path, cube):
    write_cube(tmp_path / "c.mat", cube, WL, mat_version="7.3")
    with h5py.File(tmp_path / "c.mat", "r") as f:
        assert f["img"].shape == cube.shape[::-1]  # MATLAB is column-major
        assert f["img"].attrs["MATLAB_class"] == b"single"
    assert open(tmp_path / "c.mat", "rb").read(10) == b"MATLAB 7.3"
    back, wl = read_cube(tmp_path / "c.mat")
    np.testing.assert_array_equal(back, cube)
    np.testing.assert_allclose(wl, WL)


def test_cave_folder_round_trip(tmp_path, cube):
    import imageio.v3 as iio

    folder = tmp_path / "balloons_ms"
    write_cube(folder, cube)
    names = sorted(p.name for p in folder.iterdir())
    assert names == [f"balloons_ms_{i:02d}.png" for i in range(1, WL.size + 1)]
    assert iio.imread(folder / names[0]).dtype == np.uint16
    back, wl = read_cube(folder)
    np.testing.assert_allclose(back, cube, atol=0.5 / 65535 + 1e-7)
    np.testing.assert_array_equal(wl, 400 + 10 * np.arange(WL.size))
    # Rewriting replaces the folder atomically and leaves nothing behind.
    write_cube(folder, cube[:, :, :2])
    assert len(list(folder.iterdir())) == 2
    assert _leftovers(tmp_path) == []


def test_cave_bad_cases(tmp_path, cube):
    with pytest.raises(InputError, match=r"\[0, 1\]"):
        write_cube(tmp_path / "x", cube * 2)
    with pytest.raises(InputError, match="400, 410"):
        write_cube(tmp_path / "x", cube, WL)
    assert not (tmp_path / "x").exists()
    write_cube(tmp_path / "y", cube)
    os.remove(tmp_path / "y" / "y_03.png")
    with pytest.raises(InputError, match="missing"):
        read_cube(tmp_path / "y")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no CAVE"):
        read_cube(tmp_path / "empty")
    write_cube(tmp_path / "z", cube)
    (tmp_path / "z" / "z_02.png").write_bytes(b"\x89PNG broken")
    with pytest.raises(InputError, match="z_02.png"):
        read_cube(tmp_path / "z")


@pytest.mark.parametrize("ext", [".exr", ".npz", ".npy", ".mat"])
def test_missing_empty_truncated(tmp_path, cube, ext):
    p = tmp_path / f"c{ext}"
    with pytest.raises(InputError, match="no such file"):
        read_cube(p)
    p.write_bytes(b"")
    with pytest.raises(InputError, match="empty"):
        read_cube(p)
    write_cube(p, cube, WL)
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError) as err:
        read_cube(p)
    assert str(p) in str(err.value) and "\n" not in str(err.value)


def test_mat_v73_truncated(tmp_path, cube):
    p = tmp_path / "c.mat"
    write_cube(p, cube, WL, mat_version="7.3")
    p.write_bytes(p.read_bytes()[:1500])
    with pytest.raises(InputError, match="c.mat"):
        read_cube(p)


def test_bad_contents(tmp_path, cube):
    bad = cube.copy()
    bad[1, 2, 3] = np.nan
    np.save(tmp_path / "nan.npy", bad)
    with pytest.raises(InputError, match="NaN"):
        read_cube(tmp_path / "nan.npy")
    bad[1, 2, 3] = np.inf
    np.savez(tmp_path / "inf.npz", cube=bad)
    with pytest.raises(InputError, match="NaN or Inf"):
        read_cube(tmp_path / "inf.npz")
    np.save(tmp_path / "2d.npy", cube[:, :, 0])
    with pytest.raises(InputError, match="2-D"):
        read_cube(tmp_path / "2d.npy")
    np.save(tmp_path / "cplx.npy", cube.astype(np.complex64))
    with pytest.raises(InputError, match="dtype"):
        read_cube(tmp_path / "cplx.npy")
    np.save(tmp_path / "bool.npy", cube > 0.5)
    with pytest.raises(InputError, match="dtype"):
        read_cube(tmp_path / "bool.npy")
    np.save(tmp_path / "obj.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(InputError, match="obj.npy"):
        read_cube(tmp_path / "obj.npy")
    scipy.io.savemat(tmp_path / "k.mat", {"img": cube})
    with pytest.raises(InputError, match="'cube'"):
        read_cube(tmp_path / "k.mat", key="cube")
    scipy.io.savemat(tmp_path / "two.mat", {"a": cube, "b": cube})
    with pytest.raises(InputError, match="more than one"):
        read_cube(tmp_path / "two.mat")
    np.savez(tmp_path / "wl.npz", cube=cube, wavelengths=WL[:3])
    with pytest.raises(InputError, match="3 wavelengths"):
        read_cube(tmp_path / "wl.npz")
    (tmp_path / "c.txt").write_text("hello")
    with pytest.raises(InputError, match="unsupported"):
        read_cube(tmp_path / "c.txt")


def test_exr_non_spectral_channels(tmp_path, cube):
    from recon.io.arrays import write_exr

    write_exr(tmp_path / "rgb.exr", {"R": cube[:, :, 0], "G": cube[:, :, 1]})
    with pytest.raises(InputError, match="not a spectral band"):
        read_cube(tmp_path / "rgb.exr")


def test_write_rejects_bad_arguments(tmp_path, cube):
    with pytest.raises(InputError, match="needs the wavelengths"):
        write_cube(tmp_path / "c.exr", cube)
    with pytest.raises(InputError, match="increasing"):
        write_cube(tmp_path / "c.npz", cube, WL[::-1])
    with pytest.raises(InputError, match="NaN"):
        write_cube(tmp_path / "c.npz", np.full_like(cube, np.nan), WL)
    with pytest.raises(InputError, match="does not exist"):
        write_cube(tmp_path / "nofolder" / "c.npz", cube, WL)
    assert list(tmp_path.iterdir()) == []


def test_refuses_to_overwrite_an_input(tmp_path, cube):
    p = write_cube(tmp_path / "in.npz", cube, WL)
    before = p.read_bytes()
    with pytest.raises(InputError, match="input"):
        write_cube(tmp_path / "." / "in.npz", cube * 0, WL, protect=[p])
    assert p.read_bytes() == before


def test_failed_write_leaves_no_file(tmp_path, cube, monkeypatch):
    target = tmp_path / "c.npz"

    def exploding(path, **arrays):
        with open(path, "wb") as fh:
            fh.write(b"partial")
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez_compressed", exploding)
    with pytest.raises(OSError, match="disk full"):
        write_cube(target, cube, WL)
    assert list(tmp_path.iterdir()) == []
    # An existing file survives a failed rewrite untouched.
    target.write_bytes(b"old contents")
    with pytest.raises(OSError):
        write_cube(target, cube, WL)
    assert target.read_bytes() == b"old contents"
    assert _leftovers(tmp_path) == []


def test_atomic_dir_failure_keeps_old_folder(tmp_path):
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "keep.txt").write_text("x")
    with pytest.raises(RuntimeError):
        with atomic.atomic_dir(tmp_path / "d") as tmp:
            (tmp / "new.txt").write_text("y")
            raise RuntimeError("boom")
    assert [p.name for p in (tmp_path / "d").iterdir()] == ["keep.txt"]
    assert _leftovers(tmp_path) == []


def test_standard_wavelengths():
    from recon.io.cubes import CASSI_28_WAVELENGTHS, standard_wavelengths

    wl = standard_wavelengths(28)
    assert wl.shape == (28,) and np.all(np.diff(wl) > 0)
    assert 450 < wl[0] < 455 and 645 < wl[-1] < 650
    np.testing.assert_array_equal(wl, CASSI_28_WAVELENGTHS)
    # Their spacing widens to the red, as a prism's dispersion narrows there.
    assert np.diff(wl)[0] < np.diff(wl)[-1]
    np.testing.assert_allclose(standard_wavelengths(11), np.linspace(450, 650, 11))
