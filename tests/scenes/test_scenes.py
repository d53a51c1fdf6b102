"""Built-in scenes: validity, ColorChecker data, colour-wheel rotation, natural-scene lifting,
cube files and every bad input."""

import numpy as np
import pytest

from recon.errors import InputError
from recon.io.cubes import write_cube
from scenes import colorwheel as cw
from scenes.colorchecker import patch_boxes
from scenes.natural import photo
from scenes.registry import get_scene, list_scenes
from recon.metrics import cube_to_srgb, cube_to_xyz
from scenes.spectra import illuminant

WL = np.arange(450.0, 701.0, 25.0)


@pytest.mark.parametrize("name", list_scenes())
def test_every_scene_is_finite_non_negative_and_shaped(name):
    cube, wl = get_scene(name, shape=(48, 72), wavelengths=WL)
    assert cube.shape == (48, 72, WL.size) and cube.dtype == np.float32
    assert np.all(np.isfinite(cube)) and cube.min() >= 0 and cube.max() > 0
    np.testing.assert_array_equal(wl, WL)


def test_list_scenes_has_the_built_ins():
    assert {"colorchecker", "colorwheel", "siemens_star", "bars", "natural",
            "checkerboard", "white", "line"} <= set(list_scenes())


@pytest.mark.parametrize("illum", ["D65", "A", "LED"])
def test_colorchecker_patches_match_colour_science(illum):
    import colour

    wl = np.arange(400.0, 701.0, 10.0)  # on colour-science's 5 nm grid: exact table values
    cube, _ = get_scene("colorchecker", (120, 180), wl, illuminant=illum)
    sds = list(colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"].values())
    key = {"LED": "LED-B4"}.get(illum, illum)
    ill = np.array([colour.SDS_ILLUMINANTS[key][w] for w in wl])
    ill = ill / max(colour.SDS_ILLUMINANTS[key][w] for w in np.arange(400, 721))
    boxes = patch_boxes((120, 180))
    assert len(boxes) == 24
    for k, (r0, c0, r1, c1) in enumerate(boxes):
        ref = np.array([sds[k][w] for w in wl]) * ill
        patch = cube[r0:r1, c0:c1]
        np.testing.assert_allclose(patch, np.broadcast_to(ref, patch.shape), rtol=1e-5, atol=1e-7)
    # the borders between patches are dark
    assert cube[0, :, :].max() < 0.05 and cube[:, 0, :].max() < 0.05


def test_illuminant_changes_radiance_not_reflectance():
    d65, _ = get_scene("colorchecker", (60, 90), WL, illuminant="D65")
    a, _ = get_scene("colorchecker", (60, 90), WL, illuminant="A")
    ratio_d65 = d65 / illuminant("D65", WL)
    ratio_a = a / illuminant("A", WL)
    np.testing.assert_allclose(ratio_d65, ratio_a, rtol=1e-5, atol=1e-7)
    assert not np.allclose(d65, a)


def test_colorwheel_rotation_by_a_quarter_turn_is_an_image_rotation():
    c0, _ = get_scene("colorwheel", (64, 64), WL, sectors=4, angle_deg=0.0)
    c90, _ = get_scene("colorwheel", (64, 64), WL, sectors=4, angle_deg=90.0)
    np.testing.assert_allclose(c90, np.rot90(c0), atol=1e-6)
    assert not np.allclose(c90, c0)


@pytest.mark.parametrize("n", [5, 6, 8])
def test_colorwheel_rotated_by_one_sector_maps_sectors_onto_each_other(n):
    h = w = 96
    ill = illuminant("D65", WL)
    spectra = cw.sector_reflectances(n, WL) * ill
    assert len({tuple(np.round(s, 6)) for s in spectra}) == n  # distinct sectors
    c0, _ = get_scene("colorwheel", (h, w), WL, sectors=n, angle_deg=10.0)
    c1, _ = get_scene("colorwheel", (h, w), WL, sectors=n, angle_deg=10.0 + 360.0 / n)
    y, x = np.mgrid[:h, :w] + 0.5
    theta = np.degrees(np.arctan2(h / 2 - y, x - w / 2)) - 10.0
    frac = (theta % 360.0) / (360.0 / n)
    r = np.hypot(y - h / 2, x - w / 2)
    rad = 0.45 * h
    interior = (np.abs(frac - np.round(frac)) * 360.0 / n > 4.0) & (r > 0.25 * rad) & (r < 0.9 * rad)
    k = np.floor(frac).astype(int) % n
    assert interior.sum() > 1000
    np.testing.assert_allclose(c0[interior], spectra[k[interior]], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(c1[interior], spectra[(k[interior] - 1) % n], rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("shape, n, angle, radius, hub, ss", [
    ((64, 64), 6, 0.0, 0.9, 0.15, 4),          # boundaries on the axes
    ((63, 80), 4, 90.0, 0.9, 0.15, 4),         # odd and oblong
    ((101, 97), 5, 13.7, 0.8, 0.3, 3),         # a sub-sample count that is not a power of 2
    ((200, 150), 2, 45.0, 1.0, 0.0, 2),        # no hub, the rim at the frame's edge
    ((128, 128), 16, 7.5, 0.9, 0.15, 5),       # many thin sectors
    ((360, 420), 6, 359.9, 0.9, 0.15, 4),
])
def test_colorwheel_weights_equal_the_sub_sampled_reference_to_the_bit(shape, n, angle, radius,
                                                                       hub, ss):
    fast = cw.wheel_weights(*shape, n, angle, radius, hub, ss)
    ref = cw.wheel_weights_reference(*shape, n, angle, radius, hub, ss)
    assert fast.dtype == ref.dtype == np.float32
    np.testing.assert_array_equal(fast, ref)
    # Both anti-alias: some pixels are mixtures, and every pixel's weights sum to one.
    assert np.any((ref > 0) & (ref < 1))
    np.testing.assert_allclose(ref.sum(axis=-1), 1.0, atol=1e-6)


@pytest.mark.parametrize("image", ["astronaut", "coffee"])
def test_natural_scene_renders_back_to_the_photo(image):
    wl = np.arange(400.0, 701.0, 10.0)
    cube, _ = get_scene("natural", (96, 128), wl, image=image)
    # The white is the illuminant itself (a perfect reflector): Y = 1, no colour cast.
    white = cube_to_xyz(illuminant("D65", wl)[None, None], wl)[0, 0]
    srgb = cube_to_srgb(cube, wl, white=white, peak=white[1], gamma="srgb")
    src = photo(image, (96, 128))
    for ch in range(3):
        r = np.corrcoef(srgb[..., ch].ravel(), src[..., ch].ravel())[0, 1]
        assert r > 0.99, (ch, r)
    assert np.abs(srgb - src).mean() < 0.01


def test_siemens_star_and_bars_are_binary_patterns():
    star, _ = get_scene("siemens_star", (64, 64), WL, spokes=8, aa=1)
    grey = star[..., 0] / illuminant("D65", WL)[0]
    assert set(np.unique(np.round(grey, 5))) <= {0.05, 0.9}
    bars, _ = get_scene("bars", (32, 140), WL, periods=(2, 4, 8))
    assert np.all(bars[0] == bars[-1])  # vertical bars: constant along y
    row = bars[0, :, 0] / illuminant("D65", WL)[0]
    assert np.unique(np.round(row, 5)).tolist() == [0.05, 0.9]


def test_calibration_targets():
    line, _ = get_scene("line", (16, 33), WL, width=2)
    cols = np.nonzero(line[0, :, 0])[0].tolist()
    assert cols == [16, 17] and np.all(line[:, 16] == line[0, 16])
    white, _ = get_scene("white", (8, 8), WL)
    assert np.allclose(white, 1.0)  # flat reflector under equal energy
    cb, _ = get_scene("checkerboard", (64, 64), WL, square=8)
    assert cb[0, 0, 0] != cb[0, 8, 0] and cb[0, 0, 0] == cb[8, 8, 0]


def test_cube_file_is_resampled_to_the_bands(tmp_path):
    src_wl = np.arange(400.0, 721.0, 20.0)
    yy, xx = np.mgrid[:20, :30].astype(np.float32)
    cube = (0.001 * src_wl[None, None, :] * (1 + yy[..., None] / 20)).astype(np.float32)
    path = tmp_path / "scene.npz"
    write_cube(path, cube, src_wl)
    got, wl = get_scene(str(path), shape=None, wavelengths=WL)
    np.testing.assert_allclose(got, 0.001 * WL[None, None, :] * (1 + yy[..., None] / 20), rtol=1e-5)
    small, _ = get_scene(str(path), shape=(10, 15), wavelengths=WL)
    assert small.shape == (10, 15, WL.size)
    with pytest.raises(InputError, match="nm"):
        get_scene(str(path), wavelengths=np.arange(380.0, 701.0, 10.0))
    bad = cube.copy()
    bad[0, 0, 0] = np.inf
    np.savez(tmp_path / "bad.npz", cube=bad, wavelengths=src_wl)  # write_cube refuses Inf
    with pytest.raises(InputError):
        get_scene(str(tmp_path / "bad.npz"), wavelengths=WL)
    np.save(tmp_path / "flat.npy", np.zeros((4, 4), np.float32))
    with pytest.raises(InputError):
        get_scene(str(tmp_path / "flat.npy"), wavelengths=WL, file_wavelengths=[500.0])


@pytest.mark.parametrize("args, kw", [
    (("nonsense",), {}),
    (("colorchecker",), {"shape": (1, 10)}),
    (("colorchecker",), {"shape": "big"}),
    (("colorchecker",), {"no_param": 3}),
    (("colorchecker",), {"wavelengths": np.arange(300.0, 801.0, 10.0)}),
    (("colorchecker",), {"wavelengths": [500.0, 450.0]}),
    (("colorchecker",), {"illuminant": "sunset"}),
    (("colorwheel",), {"sectors": 1}),
    (("colorwheel",), {"angle_deg": float("nan")}),
    (("natural",), {"image": "not-a-photo"}),
    (("line",), {"column": 500}),
])
def test_bad_input_raises_input_error(args, kw):
    kw.setdefault("wavelengths", WL)
    with pytest.raises(InputError):
        get_scene(*args, **kw)


def test_comb_phases_light_every_texel_exactly_once():
    from scenes.calibration import comb

    total = sum(comb((10, 13), WL, period=(3, 5), phase=(a, b))
                for a in range(3) for b in range(5))
    np.testing.assert_allclose(total, get_scene("white", shape=(10, 13), wavelengths=WL)[0])
    one = comb((10, 13), WL, period=(3, 5), phase=(1, 2))[:, :, 0]
    assert set(zip(*np.nonzero(one))) == {(y, x) for y in (1, 4, 7) for x in (2, 7, 12)}


@pytest.mark.parametrize("kw", [dict(period=(0, 5)), dict(period=(3, 20)), dict(phase=(3, 0)),
                                dict(phase=(0, -1)), dict(period="ab"), dict(reflectance=0)])
def test_comb_rejects_bad_input(kw):
    from scenes.calibration import comb

    with pytest.raises(InputError):
        comb((10, 13), WL, **kw)
