"""sim.optics.glass: Sellmeier indices, minimum deviation, total internal reflection."""

import numpy as np
import pytest

from recon.errors import InputError
from sim.optics import glass


@pytest.mark.parametrize("name, n_d, tol", [
    ("BK7", 1.5168, 1e-4), ("F2", 1.6200, 1e-4), ("SF11", 1.7847, 1e-4), ("FusedSilica", 1.4585, 1e-4),
])
def test_n_d_at_the_helium_d_line(name, n_d, tol):
    assert abs(float(glass.refractive_index(name, 587.56)) - n_d) < tol


def test_normal_dispersion_and_aliases():
    wl = np.linspace(400, 750, 50)
    n = glass.refractive_index("N-BK7", wl)
    assert np.all(np.diff(n) < 0)
    assert glass.get_glass("n-bk7") is glass.get_glass("BK7")
    with pytest.raises(InputError):
        glass.get_glass("kryptonite")
    with pytest.raises(InputError):
        glass.refractive_index("BK7", [-1.0])


def test_minimum_deviation_is_a_minimum():
    a, lam = 17.0, 575.0
    th1 = glass.min_deviation_incidence_rad("BK7", a, lam)
    n = float(glass.refractive_index("BK7", lam))

    def dev(t1):
        t2 = np.arcsin(np.sin(t1) / n)
        return t1 + np.arcsin(n * np.sin(np.radians(a) - t2)) - np.radians(a)

    ts = th1 + np.linspace(-0.05, 0.05, 101)
    assert np.argmin(dev(ts)) == 50
    assert abs(float(glass.deviation_rad("BK7", a, lam, lam)) - dev(th1)) < 1e-12


def test_impossible_apex_angles_raise():
    for a in (0.0, -3.0, 180.0, 85.0, float("nan")):
        with pytest.raises(InputError):
            glass.min_deviation_incidence_rad("BK7", a, 575.0)


def test_total_internal_reflection_is_detected_per_wavelength():
    # 82°: minimum deviation exists at 575 nm (critical apex ≈ 82.45°), but the blue end, with a
    # higher index, is totally reflected at the exit face while the red end still leaves
    flags = glass.tir_free("BK7", 82.0, 575.0, [450.0, 575.0, 700.0])
    assert flags.tolist() == [False, True, True]
    with pytest.raises(InputError, match="total internal reflection"):
        glass.deviation_rad("BK7", 82.0, 575.0, [450.0, 700.0])
    assert glass.tir_free("BK7", 17.0, 575.0, [450.0, 700.0]).all()


def test_apex_for_span_rejects_unreachable_spans():
    with pytest.raises(InputError):
        glass.apex_for_span("BK7", 1e4, 450, 700, 575, 50, 3.69)
    a = glass.apex_for_span("SF11", 60.0, 450, 700, 575, 50, 3.69)
    assert a < glass.apex_for_span("BK7", 60.0, 450, 700, 575, 50, 3.69)  # flint disperses more
