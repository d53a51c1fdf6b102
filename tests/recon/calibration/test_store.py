"""Calibration file: round trip, validation of every field, cache path, assembly."""

import json
import os

import numpy as np
import pytest

from recon.calibration.geometry import apply_homography
from recon.calibration.store import (ARRAY_FIELDS, JSON_FIELDS, Calibration, build_calibration,
                                     calibration_path, is_cached, load_cached,
                                     load_calibration, save_cached, save_calibration)
from recon.errors import InputError


def _cal(rng, design_hash="0123abcd4567ef89"):
    k, n_bands, hv, wm = 3, 4, 20, 30
    phi = np.array([[-3.0, -1.0, 0.0, 2.5]] * k) + rng.uniform(-0.2, 0.2, (k, 1))
    hb = np.stack([np.eye(3)] + [np.array([[-1, 0, wm - 1.0], [0, 1, 0.5], [0, 0, 1]])] * 2)
    return build_calibration(
        view_ids=(0, 1, 2), view_boxes=[(0, 40, hv, wm), (0, 0, hv, wm), (0, 80, hv, wm)],
        box_homographies=hb, mask_images=rng.random((k, n_bands, hv, wm)),
        wavelengths=[450.0, 500.0, 550.0, 600.0], dispersion=phi, checker_dispersion=phi[:, 2],
        design_hash=design_hash, captures=["white.exr", "line.exr"])


def test_build_normalises_and_sets_cube_shape():
    rng = np.random.default_rng(0)
    cal = _cal(rng)
    assert cal.offsets.min() == 0.0
    span = cal.offsets.max()
    assert cal.cube_shape == (20, 30 - int(np.ceil(span)), 4)
    assert cal.view_shape == cal.cube_shape[:2]
    np.testing.assert_allclose(cal.homographies[0], np.eye(3), atol=1e-12)
    np.testing.assert_array_equal(cal.gains, np.ones(4))
    # View coordinates: a centre point at view column x lands in the left view's box at the
    # flipped column, minus the left view's own offset at the checker wavelength.
    p = np.array([[5.0, 7.0]])
    o = cal.offsets[:, 2]
    box = apply_homography(np.array([[-1, 0, 29.0], [0, 1, 0.5], [0, 0, 1]]), p + [o[0], 0])
    np.testing.assert_allclose(apply_homography(cal.homographies[1], p), box - [o[1], 0])


def test_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    cal = _cal(rng)
    npz, side = save_calibration(tmp_path / "cal.npz", cal)
    assert npz.name == "cal.npz" and side.name == "cal.json"
    back = load_calibration(tmp_path / "cal")
    for name in ARRAY_FIELDS:
        np.testing.assert_array_equal(getattr(back, name), getattr(cal, name))
    assert back.mask_images.dtype == np.float32
    for name in ("view_ids", "cube_shape", "design_hash", "captures", "created"):
        assert getattr(back, name) == getattr(cal, name)
    meta = json.loads(side.read_text())
    assert set(JSON_FIELDS) <= set(meta)
    # Nothing but the two files (no temporaries left behind).
    assert sorted(os.listdir(tmp_path)) == ["cal.json", "cal.npz"]


def test_cache(tmp_path, capsys):
    rng = np.random.default_rng(2)
    cal = _cal(rng)
    p = calibration_path(tmp_path, cal.design_hash)
    assert p.parent == tmp_path and cal.design_hash in p.name
    assert load_cached(tmp_path, cal.design_hash) is None
    assert not is_cached(tmp_path, cal.design_hash)
    assert save_cached(tmp_path, cal) == p
    assert is_cached(tmp_path, cal.design_hash)
    back = load_cached(tmp_path, cal.design_hash)
    assert back.design_hash == cal.design_hash and back.created == cal.created
    np.testing.assert_array_equal(back.mask_images, cal.mask_images)
    # The cached pair is an ordinary calibration file as well (what a video's workers load).
    np.testing.assert_array_equal(load_calibration(p).offsets, cal.offsets)
    assert capsys.readouterr().err == ""
    with pytest.raises(InputError, match="plain token"):
        calibration_path(tmp_path, "../evil")
    # A file under one hash's name that holds another design is foreign: removed with one
    # warning line (the caller calibrates again), never loaded.
    other = _cal(rng, design_hash="ffff")
    npz = save_cached(tmp_path, other)
    npz.rename(calibration_path(tmp_path, "eeee"))
    npz.with_suffix(".json").rename(calibration_path(tmp_path, "eeee").with_suffix(".json"))
    assert not is_cached(tmp_path, "eeee")
    assert load_cached(tmp_path, "eeee") is None
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "calibration-eeee-" in err[0] and "'ffff'" in err[0]
    assert not list(tmp_path.glob("calibration-eeee-*"))
    # A calibration written without the cache's header and checksum is not trusted either.
    save_calibration(calibration_path(tmp_path, "eeee"), other)
    assert load_cached(tmp_path, "eeee") is None
    assert "no cache header" in capsys.readouterr().err


@pytest.mark.parametrize("missing", ARRAY_FIELDS)
def test_missing_array_field_is_named(tmp_path, missing):
    rng = np.random.default_rng(3)
    cal = _cal(rng)
    npz, _ = save_calibration(tmp_path / "cal.npz", cal)
    with np.load(npz) as z:
        arrays = {n: z[n] for n in z.files if n != missing}
    np.savez(npz, **arrays)
    with pytest.raises(InputError, match=f"missing field '{missing}'"):
        load_calibration(npz)


@pytest.mark.parametrize("missing", JSON_FIELDS)
def test_missing_json_field_is_named(tmp_path, missing):
    rng = np.random.default_rng(4)
    npz, side = save_calibration(tmp_path / "cal.npz", _cal(rng))
    meta = json.loads(side.read_text())
    del meta[missing]
    side.write_text(json.dumps(meta))
    with pytest.raises(InputError, match=f"missing field '{missing}'"):
        load_calibration(npz)


def test_corrupt_files(tmp_path):
    rng = np.random.default_rng(5)
    cal = _cal(rng)
    npz, side = save_calibration(tmp_path / "cal.npz", cal)
    with pytest.raises(InputError, match="not found"):
        load_calibration(tmp_path / "nothing.npz")
    # Object arrays would need pickle: refused.
    with np.load(npz) as z:
        arrays = {n: z[n] for n in z.files}
    arrays["gains"] = np.array([{"a": 1}] * 4, dtype=object)
    np.savez(npz, **arrays)
    with pytest.raises(InputError, match="not a readable calibration archive"):
        load_calibration(npz)
    arrays["gains"] = np.ones(5)
    np.savez(npz, **arrays)
    with pytest.raises(InputError, match="gains has shape"):
        load_calibration(npz)
    side.write_text("{not json")
    with pytest.raises(InputError, match="JSON"):
        load_calibration(npz)


def test_validation():
    rng = np.random.default_rng(6)
    cal = _cal(rng)
    good = {n: getattr(cal, n) for n in ARRAY_FIELDS}
    good.update(view_ids=cal.view_ids, cube_shape=cal.cube_shape)
    with pytest.raises(InputError, match="mask_images has 2 views"):
        Calibration(**{**good, "mask_images": cal.mask_images[:2]})
    with pytest.raises(InputError, match="increasing"):
        Calibration(**{**good, "wavelengths": cal.wavelengths[::-1]})
    with pytest.raises(InputError, match=">= 0"):
        Calibration(**{**good, "offsets": cal.offsets - 1})
    with pytest.raises(InputError, match="cube_shape"):
        Calibration(**{**good, "cube_shape": (20, 25, 5)})
    with pytest.raises(InputError, match="non-finite"):
        h = cal.homographies.copy()
        h[1, 0, 0] = np.inf
        Calibration(**{**good, "homographies": h})
    with pytest.raises(InputError, match="centre"):
        build_calibration(view_ids=(1, 2), view_boxes=cal.view_boxes[1:],
                          box_homographies=cal.homographies[1:], mask_images=cal.mask_images[1:],
                          wavelengths=cal.wavelengths, dispersion=cal.offsets[1:],
                          checker_dispersion=cal.offsets[1:, 2])


def test_cache_key_holds_the_calibration_code_version(tmp_path):
    from recon.calibration.store import CODE_VERSION, calibration_path, code_version

    p = calibration_path(tmp_path, "abc123")
    assert code_version() in p.name and p.name.startswith("calibration-abc123-v")
    assert code_version().startswith(f"{CODE_VERSION}-")
    assert calibration_path(tmp_path, "abc123", version="old") != p


def test_union_width_covers_a_mirrored_views_coded_columns():
    from recon.calibration.store import union_width

    hv, wm, wv = 20, 40, 30
    masks = np.zeros((2, 1, hv, wm), np.float32)
    masks[:, :, :, 0:24] = 0.5            # both views code view columns 0..23, guard after
    offsets = np.zeros((2, 1))
    mirror = np.array([[-1.0, 0, 29.0], [0, 1, 0], [0, 0, 1]])   # view x = 29 - centre x
    width = union_width(masks, offsets, np.stack([np.eye(3), mirror]), wv)
    # The mirror's coded columns 0..23 are centre columns 29..6: the grid must reach 29.
    assert width == 30
    assert union_width(masks, offsets, np.stack([np.eye(3), np.eye(3)]), wv) == wv


def _cal_smear(rng):
    k, n_bands, hv, wm = 3, 4, 20, 30
    phi = np.array([[-3.0, -1.0, 0.0, 2.5]] * k) + rng.uniform(-0.2, 0.2, (k, 1))
    hb = np.stack([np.eye(3)] + [np.array([[-1, 0, wm - 1.0], [0, 1, 0.5], [0, 0, 1]])] * 2)
    # Positions across each band: from half-way to the previous band centre to half-way to the
    # next (the outer bands stop at their centre, like a filter that ends there).
    edges = np.concatenate([phi[:, :1], 0.5 * (phi[:, 1:] + phi[:, :-1]), phi[:, -1:]], axis=1)
    pos = edges[:, :-1, None] + (edges[:, 1:] - edges[:, :-1])[:, :, None] * \
        ((np.arange(16) + 0.5) / 16)[None, None, :]
    return build_calibration(
        view_ids=(0, 1, 2), view_boxes=[(0, 40, hv, wm), (0, 0, hv, wm), (0, 80, hv, wm)],
        box_homographies=hb, mask_images=rng.random((k, n_bands, hv, wm)),
        wavelengths=[450.0, 500.0, 550.0, 600.0], dispersion=phi, checker_dispersion=phi[:, 2],
        design_hash="0123abcd4567ef89", band_positions=pos)


def test_smeared_fields_built_saved_and_optional(tmp_path):
    import dataclasses

    rng = np.random.default_rng(11)
    cal = _cal_smear(rng)
    assert cal.tap_start.shape == (3, 4) and cal.tap_weights.shape[:2] == (3, 4)
    np.testing.assert_allclose(cal.tap_weights.sum(axis=2), 1.0)
    # The kernels sit where the offsets say: their centroid lies between neighbouring centres.
    cen = cal.tap_start + (cal.tap_weights * np.arange(cal.tap_weights.shape[2])).sum(axis=2)
    assert np.all(np.diff(cen, axis=1) > 0)
    assert not cal.has_smeared                          # view masks not recovered yet
    hv, wv = cal.view_shape
    full = dataclasses.replace(cal, view_masks=rng.random((3, hv, wv)),
                               smear_gains=np.full(4, 2.0))
    assert full.has_smeared
    save_calibration(tmp_path / "cal", full)
    back = load_calibration(tmp_path / "cal")
    for name in ("tap_start", "tap_weights", "view_masks", "smear_gains"):
        np.testing.assert_array_equal(getattr(back, name), getattr(full, name))
    # A file without them (older code) still loads, as the shifted model only.
    save_calibration(tmp_path / "old", _cal(rng))
    old = load_calibration(tmp_path / "old")
    assert old.tap_start is None and old.view_masks is None and not old.has_smeared
    bad = [dict(view_masks=rng.random((3, hv, wv + 1))),
           dict(tap_start=None),
           dict(tap_weights=-cal.tap_weights),
           dict(tap_start=cal.tap_start + 30),
           dict(smear_gains=np.ones(3))]
    for kw in bad:
        with pytest.raises(InputError):
            dataclasses.replace(full, **kw)


def test_band_positions_sample_each_band_evenly():
    from recon.calibration.dispersion import band_positions, fit_dispersion

    lam = np.array([450.0, 500.0, 550.0, 600.0, 650.0])
    u = 1.0 / (lam * 1e-3) ** 2
    cen = np.stack([10.0 - 8.0 * (u - u[2]), 30.0 - 7.0 * (u - u[2])])     # (K=2, L) exact
    fit = fit_dispersion(lam, cen, ref_nm=550.0, degree=1)
    iv = np.stack([lam - 10.0, lam + 10.0], axis=1)
    pos = band_positions(fit, iv, samples=4)
    assert pos.shape == (2, 5, 4)
    np.testing.assert_allclose(pos[:, :, 0], fit.positions(lam - 7.5))
    np.testing.assert_allclose(pos[:, :, -1], fit.positions(lam + 7.5))
    assert np.all(np.diff(pos, axis=2) > 0)                   # longer λ lands further right
    np.testing.assert_allclose(band_positions(fit, np.stack([lam, lam], 1), 1)[..., 0], cen,
                               atol=1e-9)
    with pytest.raises(InputError):
        band_positions(fit, iv[:, ::-1])
    with pytest.raises(InputError):
        band_positions(fit, iv, samples=0)


def _with_footprint(cal, rng, grid=(6, 7)):
    """``cal`` with a random footprint matrix (rows: the boxes' pixels, columns: the texels)."""
    import dataclasses

    import scipy.sparse as sp

    n_rows = cal.n_views * int(cal.view_boxes[0, 2]) * int(cal.view_boxes[0, 3])
    a = sp.random(n_rows, cal.n_bands * grid[0] * grid[1], density=0.01, random_state=rng,
                  format="csr", dtype=np.float32)
    return dataclasses.replace(cal, footprint_grid=np.array(grid), footprint_indptr=a.indptr,
                               footprint_indices=a.indices, footprint_data=a.data,
                               footprint_gains=np.full(cal.n_bands, 1.1)), a


def test_footprint_fields_saved_selected_and_optional(tmp_path):
    rng = np.random.default_rng(7)
    cal, a = _with_footprint(_cal(rng), rng)
    assert cal.has_footprint and not _cal(rng).has_footprint
    save_calibration(tmp_path / "cal", cal)
    back = load_calibration(tmp_path / "cal")
    assert back.has_footprint
    np.testing.assert_array_equal(back.footprint_grid, [6, 7])
    np.testing.assert_array_equal(back.footprint_gains, cal.footprint_gains)
    # Rows of views 2 and 0, in that order.
    n_px = 20 * 30
    dense = a.toarray()
    np.testing.assert_array_equal(back.footprint_rows([2, 0]).toarray(),
                                  np.vstack([dense[2 * n_px:3 * n_px], dense[:n_px]]))
    with pytest.raises(InputError, match="no footprint"):
        _cal(rng).footprint_rows([0])


@pytest.mark.parametrize("change, match", [
    (dict(footprint_data=None), "come together"),
    (dict(footprint_grid=[0, 7]), "positive"),
    (dict(footprint_indptr=np.zeros(5, np.int64)), "footprint_indptr"),
    (dict(footprint_gains=np.ones(3)), "footprint_gains"),
])
def test_footprint_validation(change, match):
    import dataclasses

    rng = np.random.default_rng(8)
    cal, _ = _with_footprint(_cal(rng), rng)
    with pytest.raises(InputError, match=match):
        dataclasses.replace(cal, **change)


def test_footprint_weights_must_be_non_negative_and_on_the_grid():
    import dataclasses

    rng = np.random.default_rng(9)
    cal, _ = _with_footprint(_cal(rng), rng)
    data = cal.footprint_data.copy()
    data[0] = -1.0
    with pytest.raises(InputError, match=">= 0"):
        dataclasses.replace(cal, footprint_data=data)
    idx = cal.footprint_indices.copy()
    idx[0] = 4 * 6 * 7
    with pytest.raises(InputError, match="lie in"):
        dataclasses.replace(cal, footprint_indices=idx)
    ptr = cal.footprint_indptr.copy()
    ptr[1], ptr[2] = ptr[2] + 1, ptr[1]
    with pytest.raises(InputError, match="rise"):
        dataclasses.replace(cal, footprint_indptr=ptr)
    with pytest.raises(InputError, match="needs the footprint"):
        dataclasses.replace(_cal(rng), footprint_gains=np.ones(4))


def test_psf_saved_normalised_optional_and_validated(tmp_path):
    import dataclasses

    rng = np.random.default_rng(30)
    cal = _cal(rng)
    assert cal.psf is None
    save_calibration(tmp_path / "plain.npz", cal)
    assert load_calibration(tmp_path / "plain").psf is None
    psf = rng.random((5, 5))
    with_psf = dataclasses.replace(cal, psf=psf)
    np.testing.assert_allclose(with_psf.psf, psf / psf.sum(), rtol=1e-6)
    save_calibration(tmp_path / "psf.npz", with_psf)
    back = load_calibration(tmp_path / "psf")
    assert back.psf.dtype == np.float32
    np.testing.assert_array_equal(back.psf, with_psf.psf)
    for bad in (np.ones((4, 4)), -np.ones((3, 3)), np.ones(3)):
        with pytest.raises(InputError):
            dataclasses.replace(cal, psf=bad)


def test_noise_model_saved_optional_and_validated(tmp_path):
    import dataclasses

    rng = np.random.default_rng(31)
    cal = _cal(rng)
    assert cal.noise is None
    with_noise = dataclasses.replace(cal, noise=[0.29, 5.6])
    save_calibration(tmp_path / "noise.npz", with_noise)
    back = load_calibration(tmp_path / "noise")
    assert back.noise.dtype == np.float64
    np.testing.assert_array_equal(back.noise, [0.29, 5.6])
    for bad in ([0.0, 5.6], [0.29, -1.0], [0.29], [np.inf, 1.0]):
        with pytest.raises(InputError, match="noise model"):
            dataclasses.replace(cal, noise=bad)
