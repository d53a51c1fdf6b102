"""The simulated instrument as the application sees it: designs widened to the views a count
needs, video frames rendered from the transport, and where a calibration's grid lies on the
scene."""

import numpy as np
import pytest


def test_design_for_views():
    from kaleidospec.instrument import design_for_views, get_design

    d = get_design("small", {"band_step_nm": 50.0})
    wide = design_for_views(d, 9)
    assert wide.views == tuple(range(9)) and wide.hash != d.hash
    assert design_for_views(d, 5) is d


@pytest.mark.mitsuba
def test_renderer_matches_simulate_frame_and_never_retraces(tiny):
    from kaleidospec.instrument import FrameRenderer
    from scenes.animated import RotatingColorwheel
    from sim.transport import exact as transport
    from sim.frame import simulate_frame

    v = tiny.view_size_px
    anim = RotatingColorwheel((v, v), tiny.wavelengths, n_frames=3, speed_deg_s=45)
    r = FrameRenderer(tiny, (v, v), tiny.wavelengths)
    built = transport.STATS["built"]
    cube = anim.frame(1)
    s = r.exposure_for(cube)
    ref, meta = simulate_frame(tiny, cube, tiny.wavelengths, noise=False)
    assert s == pytest.approx(meta["radiance_scale"], rel=1e-5)
    mine = r.render(cube, radiance_scale=s, noise=False)
    # Same model; float32 sums in another order may round a count the other way.
    assert np.abs(mine - ref).max() <= 1 and np.mean(mine == ref) > 0.99
    for i in range(3):
        r.render(anim.frame(i), radiance_scale=s, seed=[0, i])
    assert transport.STATS["built"] == built  # only pixel integrals after the first trace
    noisy = [r.render(cube, radiance_scale=s, seed=[0, k]) for k in (1, 1, 2)]
    np.testing.assert_array_equal(noisy[0], noisy[1])
    assert not np.array_equal(noisy[0], noisy[2])


def test_grid_on_scene_is_where_the_centre_view_sees_the_grid(setup):
    """The centre view's answer: near the grid's middle the design's translation
    (:func:`grid_offset`) with unit square cells; across the view it follows the optics, which
    the translation does not: the centre view's noise-free model error falls against its truth
    (and rises again when the map is moved by 0.3 px)."""
    from kaleidospec.instrument import grid_on_scene, render_scene
    from kaleidospec.models import box_means, grid_offset, truth_on_grid
    from kaleidospec.reconstruct import calibrated_operator, frame_measurements

    d, cal, *_ = setup
    h, w = cal.cube_shape[:2]
    x, y = grid_on_scene(d, cal, (0,))
    oy, ox = grid_offset(d, cal)
    i, j = h // 2, w // 2
    assert abs(x[i, j] - (j + ox)) < 0.1 and abs(y[i, j] - (i + oy)) < 0.1
    np.testing.assert_allclose(np.diff(x, axis=1), 1.0, atol=0.03)
    np.testing.assert_allclose(np.diff(y, axis=0), 1.0, atol=0.03)
    frame, meta, scene, _ = render_scene("natural", d, seed=3, noise=False, native=True)
    g = frame_measurements(frame, meta, cal, (0,)).astype(np.float64)
    op = calibrated_operator(cal, (0,), "shifted")
    sx = scene.shape[1] / d.view_size_px
    moved = x + 0.3
    errors = {}
    for name, t in (("translated", _translated_truth(scene, d, cal, oy, ox)),
                    ("on the grid", truth_on_grid(scene, d, cal, view_ids=(0,))),
                    ("moved", box_means(scene, 0.5 * (moved[:-1, :-1] + moved[1:, :-1]) * sx,
                                        0.5 * (moved[:-1, 1:] + moved[1:, 1:]) * sx,
                                        0.5 * (y[:-1, :-1] + y[:-1, 1:]) * sx,
                                        0.5 * (y[1:, :-1] + y[1:, 1:]) * sx))):
        m = op.forward(np.ascontiguousarray(np.moveaxis(t, 2, 0))).astype(np.float64)
        s = float(np.vdot(g, m) / np.vdot(m, m))
        errors[name] = float(np.linalg.norm(g - s * m) / np.linalg.norm(g))
    # Measured: 7.88 % -> 7.11 % (most of what is left on these 50 nm bands is the in-band
    # smear); the map moved 0.3 px along x: 7.58 %.
    assert errors["on the grid"] < 0.95 * errors["translated"]
    assert errors["moved"] > 1.04 * errors["on the grid"]


def test_grid_on_scene_averages_the_views_answers(setup):
    """Several views: the mean of each one's answer (:func:`view_answers` at its nodes); views
    outside the calibration are refused."""
    from kaleidospec.instrument import grid_on_scene, view_answers
    from recon.errors import InputError

    d, cal, *_ = setup
    ids = list(cal.view_ids)[:3]
    each = [grid_on_scene(d, cal, (v,)) for v in ids]
    both = grid_on_scene(d, cal, ids)
    for k in range(2):
        np.testing.assert_allclose(both[k], np.mean([e[k] for e in each], axis=0), atol=1e-9)
    # The mirrored views do not put the grid where the centre does (no displacement fields on
    # `small`): the views' answers differ by a good part of a pixel.
    assert np.abs(each[1][0] - each[0][0]).max() > 0.3
    # view_answers holds the same answers where it evaluates them (the spline's nodes).
    (gy, gx), answers = view_answers(d, cal, ids)
    iy, ix = gy.astype(int), gx.astype(int)
    for v, e in zip(ids, each):
        np.testing.assert_allclose(answers[v][0], e[0][np.ix_(iy, ix)], atol=1e-9)
        np.testing.assert_allclose(answers[v][1], e[1][np.ix_(iy, ix)], atol=1e-9)
    with pytest.raises(InputError):
        grid_on_scene(d, cal, (42,))


def _translated_truth(scene, d, cal, oy, ox):
    """The truth the models were scored against before :func:`grid_on_scene`: the design grid
    translated by (oy, ox)."""
    from kaleidospec.models import shifted_area_weights

    h, w = cal.cube_shape[:2]
    v = d.view_size_px
    wy = shifted_area_weights(scene.shape[0], h, oy, scene.shape[0] / v)
    wx = shifted_area_weights(scene.shape[1], w, ox, scene.shape[1] / v)
    return np.einsum("ij,jkl,mk->iml", wy, scene, wx).astype(np.float32)
