"""The simulated instrument as the application sees it: designs widened to the views a count
needs, and video frames rendered from the transport."""

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
    from sim import transport
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
