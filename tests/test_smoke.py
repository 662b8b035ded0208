import json

from creference_bayes.cli.main import example_scene_path, main


def test_demo_writes_result(tmp_path, capsys):
    out = tmp_path / "r.json"
    assert main(["demo", "--out", str(out), "--no-posterior"]) == 0
    printed = capsys.readouterr().out
    assert "example scene (synthetic, with ground truth)" in printed and "truth" in printed
    data = json.loads(out.read_text())
    assert data["format"] == "creference-result/2"
    assert [o["id"] for o in data["objects"]] == ["tv-stand"]
    # the shipped example has ground truth, so the result is evaluated
    assert data["objects"][0]["evaluation"]["location_pct_error"] < 10.0
    assert example_scene_path().exists()
