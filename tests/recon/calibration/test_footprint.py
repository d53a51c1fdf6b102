"""Footprint calibration: the system matrix decoded from comb captures (synthetic instrument)."""

import numpy as np
import pytest
import scipy.sparse as sp

from recon.calibration.footprint import (decode_band, footprint_matrix, line_anchor,
                                         predicted_positions)
from recon.errors import InputError

K, L, HB, WB = 2, 2, 12, 16
GRID = (12, 19)
PERIOD = (3, 5)
BOXES = np.array([[0, 0, HB, WB], [0, WB, HB, WB]])
OFFSETS = np.array([[0.4, 2.7], [1.1, 3.2]])


def instrument(seed=0, err=0.4, err_x=None):
    """A random system matrix whose pixels each see a 2 x 3 patch of texels around where the
    geometry puts them (off by up to ``err`` texels, ``err_x`` along x), and the geometry's
    prediction."""
    rng = np.random.default_rng(seed)
    pred = predicted_positions(np.stack([np.eye(3)] * K), OFFSETS, (HB, WB))
    ht, wt = GRID
    rows, cols, vals = [], [], []
    for k in range(K):
        for l in range(L):
            ex = err if err_x is None else err_x
            true = pred[k, l] + rng.uniform(-1, 1, pred.shape[2:]) * np.array([err, ex])
            y0 = np.floor(true[..., 0]).astype(int)
            x0 = np.rint(true[..., 1]).astype(int) - 1
            for dy in (0, 1):
                for dx in (0, 1, 2):
                    ty, tx = y0 + dy, x0 + dx
                    w = rng.uniform(0.2, 1.0, ty.shape) * (0.3 if dy else 1.0)
                    ok = (ty >= 0) & (ty < ht) & (tx >= 0) & (tx < wt)
                    pix = k * HB * WB + np.arange(HB * WB).reshape(HB, WB)
                    rows.append(pix[ok]), cols.append((l * ht * wt + ty * wt + tx)[ok])
                    vals.append(w[ok])
    a = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(K * HB * WB, L * ht * wt))
    return a, pred


def comb_stream(a, scale=2.5, radiance=0.8, skip=None, order=None):
    """What a lab's comb captures of instrument ``a`` are: frames of the views side by side."""
    ht, wt = GRID
    yy, xx = np.mgrid[0:ht, 0:wt]
    for l in (order or range(L)):
        for p in range(PERIOD[0]):
            for q in range(PERIOD[1]):
                if (l, p, q) == skip:
                    continue
                x = np.zeros(L * ht * wt)
                lit = ((yy % PERIOD[0] == p) & (xx % PERIOD[1] == q)).ravel()
                x[l * ht * wt:(l + 1) * ht * wt][lit] = radiance
                g = (a @ x).reshape(K, HB, WB) * scale
                frame = np.concatenate(list(g), axis=1)
                yield l, (p, q), frame, {"period": list(PERIOD), "grid": list(GRID),
                                         "radiance": radiance, "radiance_scale": scale}


def test_decodes_the_system_matrix_exactly():
    a, pred = instrument()
    m, grid = footprint_matrix(comb_stream(a), BOXES, pred, floor=0.0)
    assert grid == GRID
    np.testing.assert_allclose(m.toarray(), a.toarray(), rtol=1e-5, atol=1e-6)


def test_centres_the_window_on_the_footprint_not_on_the_prediction():
    """The geometry is off by up to 1.2 texels along x (a biased homography; the period is 5):
    a window centred on the prediction would cut footprints, the centroid's does not."""
    a, pred = instrument(seed=1, err_x=1.2)
    m, _ = footprint_matrix(comb_stream(a), BOXES, pred, floor=0.0)
    np.testing.assert_allclose(m.toarray(), a.toarray(), rtol=1e-5, atol=1e-6)


def test_floor_drops_only_small_weights():
    a, pred = instrument(seed=2)
    m, _ = footprint_matrix(comb_stream(a), BOXES, pred, floor=0.05)
    assert 0 < m.nnz < a.nnz
    d = np.abs(m.toarray() - a.toarray())
    level = np.percentile(np.asarray(a[:, :GRID[0] * GRID[1]].sum(axis=1)), 99)
    assert d.max() <= 0.05 * level * 1.5


def test_line_anchor_recovers_where_the_grid_sits():
    o = np.array([[0.0, 2.0, 4.5], [1.0, 3.0, 5.0]])
    cen = 40.0 + o + 1.75            # the line at target column 40, grid column 0 = target -1.75
    cen[0, 0] += 0.8                 # a band whose line sits off its mean position
    assert line_anchor(cen, o, 40.0) == pytest.approx(-1.75)
    with pytest.raises(InputError):
        line_anchor(cen[:, :2], o, 40.0)


def test_predicted_positions_follow_homography_and_offset():
    h = np.array([[[1.0, 0, 3.0], [0, 1.0, -1.0], [0, 0, 1.0]]])
    pos = predicted_positions(h, np.array([[2.0]]), (4, 6), shift=(0.5, -1.0))
    r, c = 2, 5
    assert pos[0, 0, r, c, 1] == pytest.approx(c - 2.0 - 3.0 - 1.0)
    assert pos[0, 0, r, c, 0] == pytest.approx(r + 1.0 + 0.5)


@pytest.mark.parametrize("stream, match", [
    (lambda a: comb_stream(a, skip=(0, 1, 2)), "phases"),
    (lambda a: comb_stream(a, order=[1, 0]), "band by band"),
    (lambda a: comb_stream(a, order=[0]), "bands"),
    (lambda a: iter(()), "no comb"),
    (lambda a: ((l, p, f, {k: v for k, v in m.items() if k != "grid"})
                for l, p, f, m in comb_stream(a)), "sidecar"),
    (lambda a: comb_stream(a, scale=0.0), "positive"),
])
def test_bad_streams(stream, match):
    a, pred = instrument()
    with pytest.raises(InputError, match=match):
        footprint_matrix(stream(a), BOXES, pred)


def test_dark_band_and_mismatched_shapes():
    pred = np.zeros((K, HB, WB, 2))
    with pytest.raises(InputError, match="dark"):
        decode_band(np.zeros(PERIOD + (K, HB, WB)), pred, GRID)
    with pytest.raises(InputError, match="match"):
        decode_band(np.ones(PERIOD + (K, HB, WB)), pred[:, :-1], GRID)


def test_comb_period_exceeds_the_footprint():
    from recon.calibration.footprint import comb_period

    assert comb_period(2.74, 0.3) == (3, 5)          # `small`, 25 nm bands
    assert comb_period(4.71, 0.3) == (3, 7)          # 50 nm bands
    assert comb_period(0.0, 0.0) == (3, 2)
    assert comb_period(1.0, 1.65)[0] == 4            # `paper`'s Airy blur widens the rows too
    with pytest.raises(InputError):
        comb_period(-1.0)
