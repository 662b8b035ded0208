"""The converters against the real tools (slow; examples/check_real_tools.py does the work).

Set ``CREFERENCE_LABEL_STUDIO_VENV`` (a virtual environment with ``label-studio``) and/or
``CREFERENCE_DATUMARO_VENV`` (one with ``datumaro``); without them these tests are skipped.
A first Label Studio start on a new data folder takes about a minute.
"""

import importlib.util
import os
import warnings
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

SCRIPT = Path(__file__).resolve().parents[1] / "examples" / "check_real_tools.py"


def _venv(var):
    path = os.environ.get(var)
    if not path or not (Path(path) / "bin" / "python").exists():
        pytest.skip(f"{var} is not set to a virtual environment")
    return Path(path)


@pytest.fixture(scope="module")
def checks():
    spec = importlib.util.spec_from_file_location("check_real_tools", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def scenes(checks):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return checks.make_scenes(2, seed=3)


def test_label_studio_round_trip_through_a_real_server(checks, scenes, tmp_path):
    venv = _venv("CREFERENCE_LABEL_STUDIO_VENV")
    report = checks.check_label_studio(venv, tmp_path, scenes, port=18097)
    assert report["broken_config_rejected"]["status"] == 400
    for lines, c in report["checks"].items():
        assert c["ok"], (lines, c)


def test_datumaro_writes_and_reads_cvat_xml(checks, scenes, tmp_path):
    venv = _venv("CREFERENCE_DATUMARO_VENV")
    report = checks.check_datumaro(venv, tmp_path, scenes)
    for name, c in report["checks"].items():
        assert c["ok"], (name, c)


def test_label_studio_sdk_accepts_the_configs_and_tasks_of_several_targets(checks):
    """Label Studio's SDK validates our tasks' results (several targets, each region naming its
    target) against the shipped configs (and reports a class the config does not offer: the check
    can fail). Any environment with ``label-studio-sdk`` will do: ``CREFERENCE_LABEL_STUDIO_VENV``."""
    from test_import_labelstudio import _ctl, _street_task, tool_scene

    from creference_bayes.io.labelstudio import label_studio_config, label_studio_task

    venv = _venv("CREFERENCE_LABEL_STUDIO_VENV")
    for lines in ("keypoints", "vectors"):
        results = [a["result"] for a in label_studio_task(tool_scene(1), lines=lines)["annotations"]]
        if lines == "keypoints":
            hand = _street_task()["annotations"][0]["result"]
            results += [hand, hand + [_ctl("a2", "class", "choices", "Spaceship")]]
        errors = checks._in_venv(venv, checks._SDK_VALIDATE, {"config": label_studio_config(lines),
                                                              "results": results})
        if lines == "keypoints":
            assert "Invalid value for control 'class'" in " ".join(errors.pop())
        assert errors == [[]] * len(results[:len(errors)]), (lines, errors)
