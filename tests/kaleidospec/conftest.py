"""Fixtures shared by the tests of the application's stages."""

import pytest

#: The ``small`` design with 50 nm bands (6 of them): the stages' tests run on it.
OVR = {"band_step_nm": 50.0}


@pytest.fixture(scope="module")
def setup(shared_cache):
    """The 50 nm ``small`` design, its calibration (cached in the shared cache) and a
    ColorChecker frame with its truth: ``(design, cal, frame, meta, truth, wavelengths)``."""
    from kaleidospec.calibrate import calibrate
    from kaleidospec.instrument import get_design, render_scene

    d = get_design("small", OVR)
    cal = calibrate(d, progress=False)
    frame, meta, truth, wl = render_scene("colorchecker", d, seed=3)
    return d, cal, frame, meta, truth, wl


@pytest.fixture(scope="module")
def footprint_cal(setup):
    """The same design's calibration with the footprint model (comb captures, cached)."""
    from kaleidospec.calibrate import calibrate

    return calibrate(setup[0], progress=False, model="footprint")


#: A reduced ``small`` design (300 × 240 sensor of 40 µm pixels, 6 bands) for rendering tests.
TINY = {"sensor_pixel_um": 40, "sensor_width_px": 300, "sensor_height_px": 240,
        "mask_pitch_um": 80, "band_step_nm": 50}


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """The :data:`TINY` design with a fresh transport cache of its own for the module."""
    pytest.importorskip("mitsuba")
    import os

    from sim.transport import exact as transport
    from sim.optics.design import get_design

    old = os.environ.get("KALEIDOSPEC_CACHE")
    os.environ["KALEIDOSPEC_CACHE"] = str(tmp_path_factory.mktemp("cache"))
    transport.release()
    yield get_design("small", TINY)
    transport.release()
    if old is None:
        os.environ.pop("KALEIDOSPEC_CACHE", None)
    else:
        os.environ["KALEIDOSPEC_CACHE"] = old
