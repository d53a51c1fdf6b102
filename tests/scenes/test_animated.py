"""Animated scenes: the rotating colour wheel, a moving object, a folder of cubes."""

from __future__ import annotations

import numpy as np
import pytest

from recon.errors import InputError
from recon.io.cubes import write_cube
from scenes.animated import CubeSequence, MovingObject, RotatingColorwheel, get_animation
from scenes.colorwheel import colorwheel, sector_reflectances
from scenes.spectra import illuminant

WL = np.arange(450.0, 701.0, 50.0)
SHAPE = (64, 64)


def test_frame_is_the_wheel_at_mid_exposure():
    a = RotatingColorwheel(SHAPE, WL, n_frames=3, fps=10, exposure_ms=40, speed_deg_s=90,
                           angle0_deg=10)
    # Frame 2 opens at 0.2 s; mid-exposure 0.22 s → 10 + 90·0.22 degrees.
    want = colorwheel(SHAPE, WL, angle_deg=10 + 90 * 0.22)
    np.testing.assert_array_equal(a.frame(2), want)
    assert a.frame(2).dtype == np.float32 and a.frame(2).shape == SHAPE + (WL.size,)


def test_subframes_average_the_exposure():
    a = RotatingColorwheel(SHAPE, WL, n_frames=2, fps=10, exposure_ms=100, speed_deg_s=300,
                           subframes=4)
    ts = 0.1 + (np.arange(4) + 0.5) / 4 * 0.1
    want = np.mean([colorwheel(SHAPE, WL, angle_deg=300 * t) for t in ts], axis=0)
    np.testing.assert_allclose(a.frame(1), want, rtol=1e-5, atol=1e-7)
    # Motion blur mixes neighbouring sectors: fewer pixels hold a pure sector spectrum.
    sharp = RotatingColorwheel(SHAPE, WL, n_frames=2, fps=10, exposure_ms=100,
                               speed_deg_s=300).frame(1)
    spectra = sector_reflectances(6, WL) * illuminant("D65", WL)[None]

    def pure(c):
        d = np.abs(c[:, :, None, :] - spectra[None, None]).max(-1).min(-1)
        return int((d < 1e-4).sum())
    assert pure(a.frame(1)) < 0.8 * pure(sharp)


def test_rotation_preserves_the_total_radiance():
    a = RotatingColorwheel(SHAPE, WL, n_frames=6, speed_deg_s=77)
    totals = [a.frame(i).sum(dtype=np.float64) for i in range(6)]
    assert np.ptp(totals) / np.mean(totals) < 5e-3
    assert not np.array_equal(a.frame(0), a.frame(1))


@pytest.mark.parametrize("subframes", [1, 8])
def test_sector_masks_hold_pure_sector_spectra(subframes):
    a = RotatingColorwheel(SHAPE, WL, n_frames=3, fps=10, exposure_ms=100, speed_deg_s=60,
                           subframes=subframes)
    spectra = sector_reflectances(6, WL) * illuminant("D65", WL)[None]
    m = a.sector_masks(2)
    assert m.shape == (6,) + SHAPE and m.dtype == bool
    assert m.sum(axis=0).max() == 1  # disjoint
    cube = a.frame(2)
    for k in range(6):
        assert m[k].sum() > 20
        np.testing.assert_allclose(cube[m[k]], np.broadcast_to(spectra[k], cube[m[k]].shape),
                                   rtol=1e-5)


def test_sector_masks_on_a_shifted_grid():
    a = RotatingColorwheel(SHAPE, WL, n_frames=1, speed_deg_s=0)
    full = a.sector_masks(0)
    sub = a.sector_masks(0, grid_shape=(40, 50), offset=(5, 3))
    np.testing.assert_array_equal(sub, full[:, 5:45, 3:53])


def test_sector_masks_empty_when_the_exposure_sweeps_a_whole_sector():
    a = RotatingColorwheel(SHAPE, WL, n_frames=1, fps=10, exposure_ms=100, speed_deg_s=700)
    assert not a.sector_masks(0).any()


def test_moving_object_moves_at_its_velocity():
    a = MovingObject(SHAPE, WL, n_frames=3, fps=10, exposure_ms=10, velocity_px_s=(50, -20),
                     start_px=(20, 40), radius_px=6, background="white")
    for i in range(3):
        cov = a.coverage(i / 10 + 0.005)
        yy, xx = np.mgrid[0:SHAPE[0], 0:SHAPE[1]] + 0.5
        cx, cy = (xx * cov).sum() / cov.sum(), (yy * cov).sum() / cov.sum()
        assert abs(cx - (20 + 50 * (i / 10 + 0.005))) < 0.1
        assert abs(cy - (40 - 20 * (i / 10 + 0.005))) < 0.1
        assert abs(cov.sum() - np.pi * 36) < 1.0
    # The background is untouched away from the disc.
    f = a.frame(1)
    cov = a.coverage(0.105)
    np.testing.assert_array_equal(f[cov == 0], a.background[cov == 0])


def _npz(path, cube, wl=WL):
    np.savez(path, cube=cube.astype(np.float32), wavelengths=wl)


def test_cube_folder_in_natural_order(tmp_path):
    for k in (10, 2, 1):
        _npz(tmp_path / f"f{k}.npz", np.full((8, 9, WL.size), k, np.float32))
    (tmp_path / ".hidden.npz").write_bytes(b"junk")
    (tmp_path / "notes.txt").write_text("not a cube")
    s = CubeSequence(tmp_path, None, WL)
    assert len(s) == 3 and s.shape == (8, 9)
    assert [float(s.frame(i)[0, 0, 0]) for i in range(3)] == [1.0, 2.0, 10.0]
    s2 = get_animation(str(tmp_path), (16, 16), WL, n_frames=2)
    assert len(s2) == 2 and s2.frame(1).shape == (16, 16, WL.size)


def test_cube_folder_bad_inputs(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError, match="no cube files"):
        CubeSequence(empty, None, WL)
    shapes = tmp_path / "shapes"
    shapes.mkdir()
    _npz(shapes / "a.npz", np.ones((8, 8, WL.size)))
    _npz(shapes / "b.npz", np.ones((8, 9, WL.size)))
    with pytest.raises(InputError, match="shape"):
        CubeSequence(shapes, None, WL)
    nan = tmp_path / "nan"
    nan.mkdir()
    c = np.ones((8, 8, WL.size))
    _npz(nan / "a.npz", c)
    c[3, 3, 2] = np.nan
    _npz(nan / "b.npz", c)
    with pytest.raises(InputError, match="NaN|non-finite"):
        CubeSequence(nan, None, WL)
    wls = tmp_path / "wls"
    wls.mkdir()
    _npz(wls / "a.npz", np.ones((8, 8, WL.size)))
    _npz(wls / "b.npz", np.ones((8, 8, WL.size)), WL + 1)
    with pytest.raises(InputError, match="wavelengths"):
        CubeSequence(wls, None, WL)
    with pytest.raises(InputError, match="frames"):
        CubeSequence(shapes, None, WL, n_frames=5)
    exr = tmp_path / "exr"
    exr.mkdir()
    write_cube(exr / "a.exr", np.ones((8, 8, 3), np.float32), [500.0, 550.0, 600.0])
    with pytest.raises(InputError, match="nm"):  # does not cover 450–700 nm
        CubeSequence(exr, None, WL)


def test_bad_parameters():
    with pytest.raises(InputError, match="frame period"):
        RotatingColorwheel(SHAPE, WL, n_frames=2, fps=20, exposure_ms=100)
    with pytest.raises(InputError):
        RotatingColorwheel(SHAPE, WL, n_frames=0)
    with pytest.raises(InputError):
        RotatingColorwheel(SHAPE, WL, n_frames=2, speed_deg_s=float("nan"))
    with pytest.raises(InputError, match="no parameter"):
        get_animation("colorwheel", SHAPE, WL, spin=3)
    with pytest.raises(InputError, match="unknown animated scene"):
        get_animation("nosuchscene", SHAPE, WL)
    with pytest.raises(InputError):
        MovingObject(SHAPE, WL, n_frames=2, patch=30)
    a = RotatingColorwheel(SHAPE, WL, n_frames=2)
    with pytest.raises(InputError):
        a.frame(2)
