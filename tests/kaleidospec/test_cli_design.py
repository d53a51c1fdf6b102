"""``kaleidospec design show``: JSON on stdout, one-line errors with exit status 2."""

import json
import subprocess
import sys

import pytest

from sim.optics.design import get_design


def _run(*args):
    return subprocess.run([sys.executable, "-m", "kaleidospec.cli", "design", "show", *args],
                          capture_output=True, text=True, timeout=120)


def test_design_show_prints_the_design_as_json():
    p = _run()
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    d = get_design("paper")
    assert out["prism_apex_deg"] == 17.0 and out["imaging_focal_mm"] == 50.0
    assert out["sensor_pixel_um"] == 3.69 and out["hash"] == d.hash
    der = out["derived"]
    assert der["view_size_px"] == d.view_size_px and der["views_fit"] is True
    assert der["dispersion_span_px"] == pytest.approx(d.dispersion_span_px)


def test_design_show_small_with_overrides():
    p = _run("--design", "small", "--set", "prism_apex_deg=25", "--set", "views=0,1,2")
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    want = get_design("small", {"prism_apex_deg": "25", "views": "0,1,2"})
    assert out["prism_apex_deg"] == 25.0 and out["views"] == [0, 1, 2]
    assert out["hash"] == want.hash != get_design("small").hash


@pytest.mark.parametrize("args", [
    ("--set", "no_such_field=3"), ("--set", "prism_apex_deg=steep"), ("--set", "prism_apex_deg"),
    ("--design", "giant"), ("--set", "prism_apex_deg=95"),
])
def test_bad_design_input_exits_2_with_one_line(args):
    p = _run(*args)
    assert p.returncode == 2
    assert p.stdout == ""
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("kaleidospec: error:")
