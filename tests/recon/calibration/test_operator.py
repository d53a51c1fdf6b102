"""End to end: calibrate from captures made by a known operator, then compare operators.

The "instrument" is H1's ideal ``kaleidoscope_cassi`` (5 views, flips, integer dispersion) with
its views placed on a sensor; every capture (white, line, checkerboard) is that operator applied
to a calibration scene.  The calibration sees only the sensor frames.
"""

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from recon.calibration import (build_calibration, find_view_boxes, fit_dispersion,
                               line_centroids, mask_images, measurements,
                               operator_from_calibration, view_homographies)
from recon.calibration.geometry import apply_homography
from recon.calibration.views import VIEW_GRID
from recon.errors import InputError
from recon.operators import dot_test
from recon.operators.cassi import kaleidoscope_cassi

IDS = (0, 1, 2, 3, 4)
HV, WV = 96, 128
LAM = np.array([450.0, 500.0, 550.0, 600.0, 650.0])
PHI = np.array([-7.0, -3.0, 0.0, 2.0, 4.0])           # relative to 550 nm
GAP = 8
HASH = "feedc0ffee123456"


class Instrument:
    def __init__(self, rng, noise=0.002):
        cells = rng.random((len(IDS), HV // 2, WV // 2)) < 0.5
        self.masks = np.kron(cells, np.ones((1, 2, 2))).astype(np.float32)
        self.op = kaleidoscope_cassi(self.masks, PHI, n_views=len(IDS))
        _, self.hv, self.wm = self.op.oshape
        self.shape = (GAP + 3 * (self.hv + GAP), GAP + 3 * (self.wm + GAP))
        self.boxes = np.array([(GAP + r * (self.hv + GAP), GAP + c * (self.wm + GAP),
                                self.hv, self.wm) for r, c in (VIEW_GRID[v] for v in IDS)])
        self.rng, self.noise = rng, noise

    def frame(self, g, level=1000.0):
        f = np.zeros(self.shape)
        for (y0, x0, h, w), gk in zip(self.boxes, g):
            f[y0:y0 + h, x0:x0 + w] = gk
        f = level * f + self.noise * level * self.rng.standard_normal(f.shape)
        return f.astype(np.float32)

    def capture(self, cube, level=1000.0):
        return self.frame(self.op.forward(cube.astype(np.float32)), level)


def _board(h, w, sq=12, origin=(10, 6), n=(9, 7)):
    yy, xx = np.mgrid[0:h, 0:w]
    u, v = (xx - origin[0]) // sq, (yy - origin[1]) // sq
    inside = (u >= 0) & (u < n[0]) & (v >= 0) & (v < n[1])
    return np.where(inside & ((u + v) % 2 == 0), 0.1, 1.0)


@pytest.fixture(scope="module")
def calibrated():
    rng = np.random.default_rng(0)
    inst = Instrument(rng)
    n_bands = LAM.size
    unit = np.zeros((n_bands, HV, WV))
    whites, lines = [], []
    for l in range(n_bands):
        cube = unit.copy()
        cube[l] = 1.0
        whites.append(inst.capture(cube))
        cube = unit.copy()
        cube[l, :, 60] = 1.0
        lines.append(inst.capture(cube, level=3000.0))
    whites, lines = np.stack(whites), np.stack(lines)
    cube = unit.copy()
    cube[2] = _board(HV, WV)
    checker = inst.capture(cube)

    boxes = find_view_boxes(whites, IDS)
    fit = fit_dispersion(LAM, line_centroids(lines, boxes), ref_nm=550.0, degree=4)
    cal = build_calibration(
        view_ids=IDS, view_boxes=boxes,
        box_homographies=view_homographies(checker, whites[2], boxes, IDS, (8, 6)),
        mask_images=mask_images(whites, boxes), wavelengths=LAM, dispersion=fit(LAM),
        checker_dispersion=fit([550.0])[:, 0], design_hash=HASH,
        captures=["white", "line", "checker"])
    return inst, cal


def test_calibration_matches_the_instrument(calibrated):
    inst, cal = calibrated
    np.testing.assert_array_equal(cal.view_boxes, inst.boxes)
    np.testing.assert_allclose(cal.offsets, np.broadcast_to(PHI - PHI.min(), cal.offsets.shape),
                               atol=0.1)
    assert cal.cube_shape == (HV, WV, LAM.size)
    # Homographies: the mirror flips, to 0.3 px at the board's corners (inner and outer).
    pts = np.stack(np.meshgrid(9.5 + 12 * np.arange(10), 5.5 + 12 * np.arange(8)),
                   -1).reshape(-1, 2)
    flips = {0: (), 1: (1,), 2: (1,), 3: (0,), 4: (0,)}
    for k, v in enumerate(IDS):
        q = pts.copy()
        if 1 in flips[v]:
            q[:, 0] = WV - 1 - q[:, 0]
        if 0 in flips[v]:
            q[:, 1] = HV - 1 - q[:, 1]
        err = np.linalg.norm(apply_homography(cal.homographies[k], pts) - q, axis=1).max()
        assert err < 0.3, (v, err)


def test_calibrated_operator_reproduces_measurements(calibrated):
    inst, cal = calibrated
    op = operator_from_calibration(cal)
    assert op.ishape == inst.op.ishape and op.oshape == inst.op.oshape
    rng = np.random.default_rng(1)
    cube = gaussian_filter(rng.random((LAM.size, HV, WV)), (0, 2.0, 2.0)).astype(np.float32)
    frame = inst.capture(cube)
    g = measurements(frame, cal, metadata={"design_hash": HASH}) / 1000.0
    rel = np.linalg.norm(op.forward(cube) - g) / np.linalg.norm(g)
    assert rel < 0.02, rel
    # A subset of views in another order is the matching subset of the measurement.
    sub = operator_from_calibration(cal, (2, 0))
    np.testing.assert_allclose(sub.forward(cube), op.forward(cube)[[2, 0]], rtol=1e-5, atol=1e-6)
    gs = measurements(frame, cal, (2, 0))
    np.testing.assert_array_equal(gs, measurements(frame, cal)[[2, 0]])
    assert dot_test(sub) < 1e-6


def test_bad_inputs(calibrated):
    inst, cal = calibrated
    frame = np.zeros(inst.shape, dtype=np.float32)
    with pytest.raises(InputError, match="design"):
        measurements(frame, cal, metadata={"design_hash": "0000"})
    with pytest.raises(InputError, match="not in the calibration"):
        operator_from_calibration(cal, (0, 5))
    with pytest.raises(InputError, match="smaller"):
        measurements(frame[:50], cal)
    with pytest.raises(InputError, match="2-D"):
        measurements(frame[None], cal)
    with pytest.raises(InputError, match="Calibration"):
        operator_from_calibration({"view_ids": IDS})


def _two_views(rng, k, n_bands, hv, wm):
    """A centre and a mirrored view, three bands with smear sampling positions (the smeared
    model's input), random mask images."""
    phi = np.array([[0.0, 2.2, 4.0]] * k)
    pos = np.stack([phi - 0.6, phi + 0.6], axis=2).clip(0, 4.0)
    return build_calibration(
        view_ids=(0, 1), view_boxes=[(0, 30, hv, wm), (0, 0, hv, wm)],
        box_homographies=np.stack([np.eye(3), np.array([[-1, 0, wm - 1.0], [0, 1, 0],
                                                        [0, 0, 1]])]),
        mask_images=rng.random((k, n_bands, hv, wm)), wavelengths=[450.0, 550.0, 650.0],
        dispersion=phi, checker_dispersion=phi[:, 1], band_positions=pos, grid="centre")


def test_model_selection_smeared_and_shifted():
    import dataclasses

    from recon.calibration.operator import operator_from_calibration
    from recon.operators import CalibratedCassi, SmearedCassi

    rng = np.random.default_rng(21)
    k, n_bands, hv, wm = 2, 3, 12, 24
    cal = _two_views(rng, k, n_bands, hv, wm)
    shifted = operator_from_calibration(cal)                    # no view masks yet: "auto"
    assert isinstance(shifted, CalibratedCassi)
    with pytest.raises(InputError, match="recalibrate"):
        operator_from_calibration(cal, model="smeared")
    with pytest.raises(InputError):
        operator_from_calibration(cal, model="exact")
    hv_, wv = cal.view_shape
    full = dataclasses.replace(cal, view_masks=rng.random((k, hv_, wv)))
    op = operator_from_calibration(full, (1, 0))
    assert isinstance(op, SmearedCassi) and op.oshape == (2, hv, wm)
    assert op.ishape == (n_bands,) + tuple(cal.cube_shape[:2])
    assert dot_test(op, rng) < 1e-6
    assert isinstance(operator_from_calibration(full, model="shifted"), CalibratedCassi)
    # band_scale multiplies each band of either model.
    scale = np.array([0.5, 2.0, 1.5])
    x = rng.random(op.ishape)
    for model in ("smeared", "shifted"):
        a = operator_from_calibration(full, model=model)
        b = operator_from_calibration(full, model=model, band_scale=scale)
        np.testing.assert_allclose(b.forward(x), a.forward(x * scale[:, None, None]),
                                   rtol=1e-5, atol=1e-6)
    # The shifted model scales its weights, not a copy of the mask images (a run of
    # consecutive views is a slice of the calibration's; other orders are gathered).
    b = operator_from_calibration(full, model="shifted", band_scale=scale)
    assert np.shares_memory(b.mask_images, full.mask_images)
    assert np.array_equal(b.band_scale, scale)
    swapped = operator_from_calibration(full, (1, 0), model="shifted", band_scale=scale)
    assert np.array_equal(swapped.mask_images, full.mask_images[::-1])


def test_footprint_model_is_its_matrix_rows_with_the_band_scale():
    import dataclasses

    import scipy.sparse as sp

    from recon.calibration.operator import operator_from_calibration, resolve_model
    from recon.operators import SparseMatrixOperator

    rng = np.random.default_rng(22)
    k, n_bands, hv, wm = 2, 3, 6, 10
    phi = np.array([[0.0, 1.0, 2.0]] * k)
    cal = build_calibration(
        view_ids=(0, 1), view_boxes=[(0, 12, hv, wm), (0, 0, hv, wm)],
        box_homographies=np.stack([np.eye(3)] * 2), mask_images=rng.random((k, n_bands, hv, wm)),
        wavelengths=[450.0, 550.0, 650.0], dispersion=phi, checker_dispersion=phi[:, 1])
    with pytest.raises(InputError, match="comb"):
        operator_from_calibration(cal, model="footprint")
    grid = (5, 8)
    a = sp.random(k * hv * wm, n_bands * grid[0] * grid[1], density=0.05, random_state=rng,
                  format="csr", dtype=np.float32)
    fp = dataclasses.replace(cal, footprint_grid=np.array(grid), footprint_indptr=a.indptr,
                             footprint_indices=a.indices, footprint_data=a.data)
    assert resolve_model(fp, "auto") == "footprint"
    scale = np.array([0.5, 2.0, 1.5])
    op = operator_from_calibration(fp, (1, 0), model="footprint", band_scale=scale)
    assert isinstance(op, SparseMatrixOperator)
    assert op.ishape == (n_bands,) + grid and op.oshape == (2, hv, wm)
    assert dot_test(op, rng) < 1e-6
    x = rng.random(op.ishape)
    dense = a.toarray()
    n = hv * wm
    want = np.vstack([dense[n:], dense[:n]]) @ (x * scale[:, None, None]).ravel()
    np.testing.assert_allclose(op.forward(x).ravel(), want, rtol=1e-5, atol=1e-6)
    # The calibration's own weights are untouched by the scale.
    np.testing.assert_array_equal(fp.footprint_data, a.data)


def test_a_calibrated_psf_blurs_the_shifted_and_smeared_models_not_the_footprint():
    import dataclasses

    import scipy.sparse as sp

    from recon.calibration import airy_kernel
    from recon.calibration.operator import operator_from_calibration
    from recon.operators.blur import BlurredOperator, convolve_views

    rng = np.random.default_rng(23)
    k, n_bands, hv, wm = 2, 3, 12, 24
    cal = _two_views(rng, k, n_bands, hv, wm)
    hv_, wv = cal.view_shape
    a = sp.random(k * hv * wm, n_bands * 5 * 8, density=0.05, random_state=rng, format="csr",
                  dtype=np.float32)
    cal = dataclasses.replace(cal, view_masks=rng.random((k, hv_, wv)),
                              footprint_grid=np.array((5, 8)), footprint_indptr=a.indptr,
                              footprint_indices=a.indices, footprint_data=a.data)
    psf = airy_kernel(1.6)
    blurred = dataclasses.replace(cal, psf=psf * 3.0)
    np.testing.assert_allclose(blurred.psf.sum(), 1.0, rtol=1e-6)   # stored normalised
    for model in ("shifted", "smeared"):
        sharp = operator_from_calibration(cal, model=model)
        op = operator_from_calibration(blurred, model=model)
        assert isinstance(op, BlurredOperator) and not isinstance(sharp, BlurredOperator)
        x = rng.random(op.ishape).astype(np.float32)
        np.testing.assert_allclose(op.forward(x), convolve_views(sharp.forward(x), blurred.psf),
                                   rtol=1e-5, atol=1e-6)
        assert dot_test(op, rng) < 1e-6
    assert not isinstance(operator_from_calibration(blurred, model="footprint"),
                          BlurredOperator)


def test_view_fields_go_into_every_view_warp_in_view_coordinates(tmp_path):
    """Box fields become view-coordinate fields (view column x_v is box column x_v + o_k at
    the board's wavelength); every view, the centre too, warps the grid through its
    homography and field, a led view with its field moved by its lead; saved and loaded."""
    import dataclasses

    from calibrations import (BOX_HOMOGRAPHIES, HV, PHI, WM, K, L,
                              three_view_calibration)
    from recon.calibration import load_calibration, save_calibration
    from recon.calibration.extent import led_view
    from recon.operators import CalibratedCassi, DisplacementField, HomographyWarp

    rng = np.random.default_rng(9)
    k, n_bands, hv, wm = K, L, HV, WM
    masks = (rng.random((k, n_bands, hv, wm)) > 0.5).astype(np.float32)
    box = [DisplacementField(0.3 * rng.uniform(-1, 1, (2, 6)), (wm / 2, hv / 2, wm / 2, hv / 2))
           for _ in range(k)]
    cal = three_view_calibration(masks, box_fields=box)
    phi = np.stack([PHI] * k)
    chk = phi[:, 2] - phi.min()
    xs, ys = rng.uniform(0, wm, 8), rng.uniform(0, hv, 8)
    for i in (1, 2):
        np.testing.assert_allclose(np.stack(cal.field(i)(xs - chk[i], ys)),
                                   np.stack(box[i](xs, ys)), atol=1e-12)
    # The centre keeps only its bend (its affine part went into the other homographies)...
    assert np.all(cal.view_fields[0][:, :3] == 0)
    np.testing.assert_allclose(cal.view_fields[0][:, 3:], box[0].coeffs[:, 3:])
    # ... and a scene point still lands where the fields and homographies put it: centre pixel
    # x0 = g + d0(g), view pixel H g + d(H g), before (from the box data) and after.
    from recon.calibration.geometry import apply_homography, to_view_coordinates

    h_view = to_view_coordinates(BOX_HOMOGRAPHIES, chk)
    d0 = box[0].moved(-chk[0])
    g = np.stack([rng.uniform(5, 30, 8), rng.uniform(2, 10, 8)], axis=1)
    x0 = g + np.stack(d0(*g.T), axis=1)
    g_new = x0 - np.stack(cal.field(0)(*x0.T), axis=1)
    for i in (1, 2):
        di = box[i].moved(-chk[i])
        before = apply_homography(h_view[i], g)
        before = before + np.stack(di(*before.T), axis=1)
        after = apply_homography(cal.homographies[i], g_new)
        after = after + np.stack(cal.field(i)(*after.T), axis=1)
        # First order in the fields: here up to 0.3 px, changing by 0.05 px a pixel.
        np.testing.assert_allclose(after, before, atol=0.04)
    cal = dataclasses.replace(cal, view_leads=np.array([0, 3, 0]))
    op = operator_from_calibration(cal, model="shifted")
    h, w, _ = cal.cube_shape
    wv = cal.view_shape[1]
    warps, offsets = [], []
    for i, lead in enumerate((0, 3, 0)):
        m, o = led_view(cal.homographies[i], cal.offsets[i], lead)
        warps.append(HomographyWarp(m, (h, w), (h, wv + lead),
                                    view_field=cal.field(i).moved(lead)))
        offsets.append(o)
    by_hand = CalibratedCassi(cal.mask_images, np.stack(offsets), warps, (n_bands, h, w))
    x = rng.random(op.ishape).astype(np.float32)
    np.testing.assert_array_equal(op.forward(x), by_hand.forward(x))
    plain = operator_from_calibration(
        dataclasses.replace(cal, view_fields=None, view_field_frames=None), model="shifted")
    assert np.abs(op.forward(x) - plain.forward(x)).max() > 0.05
    save_calibration(tmp_path / "cal", cal)
    back = load_calibration(tmp_path / "cal")
    np.testing.assert_array_equal(back.view_fields, cal.view_fields)
    np.testing.assert_array_equal(back.view_field_frames, cal.view_field_frames)
    with pytest.raises(InputError, match="go together"):
        dataclasses.replace(cal, view_field_frames=None)
    with pytest.raises(InputError, match="view_fields"):
        dataclasses.replace(cal, view_fields=cal.view_fields[:2])
