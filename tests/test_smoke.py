import json

from creference_bayes.cli.main import example_scene_path, main


def test_demo_writes_result(tmp_path, capsys):
    out = tmp_path / "r.json"
    assert main(["demo", "--out", str(out), "--quiet"]) == 0
    data = json.loads(out.read_text())
    assert data["format"] == "creference-result/1"
    assert set(data["map"]) == {"x", "y", "z", "yaw", "focal_length_px", "pitch", "roll"}
    # the shipped example has ground truth, so the result is evaluated
    assert data["evaluation"]["location_pct_error"] < 10.0
    assert example_scene_path().exists()
