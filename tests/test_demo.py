"""The main job: `safemanip demo` runs the shipped policy (and the scripted baseline and the planner) end to end."""

import json

import pytest

from safemanip.cli import main
from safemanip.demo import run_demo
from safemanip.env.slide_out import EVENTS


def test_policy_demo_writes_a_summary_with_margins(tmp_path):
    result = run_demo(out_dir=tmp_path, video=False)
    summary = json.loads(result.summary.read_text())
    assert summary["outcome"] in EVENTS and summary["outcome"] != "running"
    assert summary["controller"].startswith("policy rarl-k2-conservative")
    trace = summary["margins_over_time"]
    assert len(trace) == result.steps + 1  # the reset state and every step
    assert trace[-1]["t"] == result.steps
    assert all(len(s) == 2 for s in summary["selected_over_time"][1:])  # k = 2 objects shown to the policy


def test_scripted_demo_on_an_empty_table_succeeds_and_writes_a_video(tmp_path, gl):
    pytest.importorskip("imageio")
    result = run_demo(out_dir=tmp_path, controller="scripted", n_objects=0, seed=1, slowmo=2.0)
    assert result.event == "success"
    assert result.video is not None and result.video.stat().st_size > 1000
    summary = json.loads(result.summary.read_text())
    # frames rendered between control steps: 50 per simulated second (plus the reset frame)
    assert summary["video_frames"] == 1 + (result.steps * 5) // 2
    assert summary["video_frames"] / (result.steps * 0.05) >= 30
    import imageio.v3 as iio

    if result.video.suffix == ".mp4":
        assert iio.immeta(result.video)["fps"] == pytest.approx(25.0)  # 50 frames per simulated second, 2x slower


def test_planner_demo_in_the_default_scene_runs_through_the_cli(tmp_path, capsys):
    code = main(["demo", "--controller", "planner", "--out", str(tmp_path), "--no-video"])
    assert code == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["controller"].startswith("planner")
    assert summary["outcome"] in EVENTS and summary["outcome"] != "running"
    assert "planner" in capsys.readouterr().out


def test_demo_cli_reports_errors_without_a_traceback(tmp_path, capsys):
    code = main(["demo", "--out", str(tmp_path), "--policy", "no-such-policy", "--no-video"])
    assert code == 2
    assert "no policy file" in capsys.readouterr().err
