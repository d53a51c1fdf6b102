"""tools/bench_video.py --priors: the modes it compares and how it sums a run's frames."""

from __future__ import annotations

import pytest

from tool_scripts import load_tool


def _tool():
    return load_tool("bench_video")


def test_modes_are_frame_by_frame_the_long_cold_run_the_chain_and_each_temporal_weight():
    """Frame by frame is one-frame segments; its long variant runs the iterations the chain has
    run by its last frame; only the chained modes carry a temporal weight."""
    modes = _tool().prior_modes(frames=6, iters=15, cold_iters=50, temporal=[0.01, 0.05])
    labels = [m[0] for m in modes]
    assert labels == ["frame by frame", "frame by frame x125", "chain",
                      "chain + temporal 0.01", "chain + temporal 0.05"]
    kw = dict(modes)
    assert kw["frame by frame"] == {"segment_frames": 1}
    assert kw["frame by frame x125"] == {"segment_frames": 1, "cold_iters": 125}
    assert kw["chain"] == {}
    assert kw["chain + temporal 0.05"] == {"temporal": 0.05}


def test_frame_summary_means_all_frames_but_times_only_the_warm_ones():
    """Frame 0 is a cold solve in every mode, so its time is left out; the frames may come in
    any order."""
    rows = [{"frame": 1, "psnr": 30.0, "ssim": 0.8, "sam_deg": 4.0, "solve_seconds": 0.2},
            {"frame": 0, "psnr": 20.0, "ssim": 0.6, "sam_deg": 8.0, "solve_seconds": 9.0},
            {"frame": 2, "psnr": 25.0, "ssim": 0.7, "sam_deg": 6.0, "solve_seconds": 0.4}]
    psnr, ssim, sam, sec = _tool().frame_summary(rows)
    assert psnr == pytest.approx(25.0)
    assert ssim == pytest.approx(0.7)
    assert sam == pytest.approx(6.0)
    assert sec == pytest.approx(0.3)
    with pytest.raises(ValueError):
        _tool().frame_summary(rows[:1])


def test_unknown_prior_is_refused_before_any_work(capsys):
    with pytest.raises(SystemExit) as e:
        _tool().main(["--priors", "tv,nonesuch"])
    assert e.value.code == 2
    assert "unknown prior 'nonesuch'" in capsys.readouterr().err


@pytest.mark.parametrize("argv, message", [
    (["--priors", "tv", "--temporal", "0.01,x"], "comma-separated numbers"),
    (["--priors", "tv", "--temporal", "-0.1"], "temporal weights > 0"),
    (["--priors", "tv", "--frames", "1"], "--frames >= 2"),
])
def test_bad_comparison_settings_are_refused_before_any_work(argv, message, capsys):
    with pytest.raises(SystemExit) as e:
        _tool().main(argv)
    assert e.value.code == 2
    assert message in capsys.readouterr().err
