"""What a new user met with scenes of several objects (issue 36): each behaviour a user expects,
checked through the command line or the Python API the way the docs show them."""

import json

import pytest

import creference_bayes as cb
from creference_bayes.cli.main import main
from creference_bayes.io.scene import SceneError

FAST = ["--min-ess", "50", "--max-steps", "2000", "--quiet"]


@pytest.fixture(scope="module")
def frame_file(tmp_path_factory):
    d = tmp_path_factory.mktemp("frames")
    assert main(["simulate", str(d), "--n", "1", "--objects", "2", "--seed", "3", "--quiet"]) == 0
    return next(d.glob("*.json"))


def _with_class(frame_file, tmp_path, cls: str):
    """The simulated frame with its first target's class replaced by ``cls`` (no known sizes)."""
    data = json.loads(frame_file.read_text())
    t = data["targets"][0]
    t.pop("dimensions_m", None)
    t["class"] = cls
    path = tmp_path / "kayak.json"
    path.write_text(json.dumps(data))
    return path


KAYAK = {"Kayak": {"length_m": 4.0, "width_m": 0.7, "height_m": 0.4, "log_sd": 0.1}}


def test_a_classes_file_gives_the_size_prior_to_estimate_batch_and_python(frame_file, tmp_path, capsys):
    path = _with_class(frame_file, tmp_path, "Kayak")
    classes = tmp_path / "classes.json"
    classes.write_text(json.dumps(KAYAK))
    # without the file: refused, naming the class and the option
    assert main(["estimate", str(path), "--no-posterior", "--quiet"]) == 2
    assert "Kayak" in capsys.readouterr().err
    # with it: estimate, batch and the Python API take it
    assert main(["estimate", str(path), "--no-posterior", "--classes", str(classes), "--out",
                 str(tmp_path / "r.json"), "--quiet"]) == 0
    assert json.loads((tmp_path / "r.json").read_text())["objects"][0]["class"] == "Kayak"
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "kayak.json").write_text(path.read_text())
    assert main(["batch", str(tmp_path / "in"), "--out", str(tmp_path / "b"), "--classes", str(classes),
                 "--workers", "1", "--no-posterior", "--quiet"]) == 0
    assert (tmp_path / "b" / "results" / "kayak.json").is_file()
    from creference_bayes.models.size_priors import size_priors_from_dict

    r = cb.estimate(path, classes=size_priors_from_dict(KAYAK), posterior=False)
    assert r.to_dict()["objects"][0]["map"]["length_m"] > 0


def test_a_class_name_in_lower_case_is_the_kitti_class(frame_file, tmp_path):
    """KITTI's evaluation ignores the case of class names; so does the size prior's look-up."""
    path = _with_class(frame_file, tmp_path, "car")
    scene = cb.load_scene(path)
    assert scene.size_prior("car") is scene.size_prior("Car") is not None
    assert scene.targets[0].cls == "car"


def test_python_estimates_take_any_scene_as_a_path_or_a_dict(frame_file):
    data = json.loads(frame_file.read_text())
    by_path = cb.estimate(str(frame_file), posterior=False, seed=0)
    by_dict = cb.estimate(data, posterior=False, seed=0)
    by_scene = cb.estimate(cb.parse_scene(data), posterior=False, seed=0)
    maps = [r.to_dict()["objects"][0]["map"]["distance_m"] for r in (by_path, by_dict, by_scene)]
    assert maps[0] == maps[1] == maps[2]


@pytest.mark.parametrize("fmt, words", [("creference-scene/3", "does not know"),
                                        ("creference-result/2", "give the scene"),
                                        ("something", "expected 'creference-scene/1' or 'creference-scene/2'")])
def test_a_wrong_format_says_what_is_read(frame_file, fmt, words):
    data = json.loads(frame_file.read_text())
    data["format"] = fmt
    with pytest.raises(SceneError, match=words):
        cb.parse_scene(data)


def test_an_unreadable_file_is_named(capsys):
    """A read that fails after the file opened (here: /proc/self/mem, which gives EIO) names the file."""
    assert main(["estimate", "/proc/self/mem", "--quiet"]) == 2
    assert capsys.readouterr().err.strip() == "error: /proc/self/mem: Input/output error"


@pytest.mark.slow  # a batch, two plots and two advices (about 35 s); test_batch.py plots and advises a batch too
def test_plot_and_advise_use_the_batch_folders_scene(tmp_path):
    """A batch result is named like its scene; plot and advise find the batch folder's copy of the
    scene, for a scene of several objects and for a one-target scene alike."""
    scenes = tmp_path / "scenes"
    assert main(["simulate", str(scenes / "one"), "--n", "1", "--quiet"]) == 0
    assert main(["simulate", str(scenes / "frames"), "--n", "1", "--objects", "2", "--quiet"]) == 0
    assert main(["batch", str(scenes), "--out", str(tmp_path / "b"), "--workers", "1", *FAST]) == 0
    results = sorted((tmp_path / "b" / "results").rglob("*.json"))
    assert len(results) == 2
    for k, r in enumerate(results):
        assert main(["plot", str(r), "--out", str(tmp_path / f"figs{k}"), "--quiet"]) == 0
        assert any((tmp_path / f"figs{k}").glob("*boxes.png"))
        assert main(["advise", str(r), "--quiet", "--draws", "100", "--futures", "20",
                     "--out", str(tmp_path / f"advice{k}.json")]) == 0


def test_confidence_fit_names_the_file_it_cannot_read(frame_file, tmp_path, capsys):
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "a.json").write_text(frame_file.read_text())
    (tmp_path / "in" / "f.json").write_text('{"format": "creference-scene/2", "image": ')
    assert main(["confidence", "fit", str(tmp_path / "in"), "--out", str(tmp_path / "m.json")]) == 2
    assert str(tmp_path / "in" / "f.json") in capsys.readouterr().err


def test_simulate_from_kitti_refuses_options_it_would_ignore(tmp_path, capsys):
    (tmp_path / "k" / "label_2").mkdir(parents=True)
    (tmp_path / "k" / "calib").mkdir()
    assert main(["simulate", "--from-kitti", str(tmp_path / "k"), "--out", str(tmp_path / "o"),
                 "--objects", "5"]) == 2
    assert "--objects" in capsys.readouterr().err


def test_the_help_says_what_simulate_and_estimate_take_and_write(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    out = "".join(capsys.readouterr().out.split())  # argparse wraps the text anywhere
    assert "syntheticsceneswithgroundtruth(creference-scene/2)" in out
    with pytest.raises(SystemExit):
        main(["estimate", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "creference-scene/1 (one target) or creference-scene/2 (one or more" in out
    assert "creference-result/2" in out and "creference-result/1" not in out
