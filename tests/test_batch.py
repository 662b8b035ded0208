"""creference batch: discovery, seeds, resume, failure isolation, the local pool and Dask."""

import csv
import json
import math
import shutil
import time

import numpy as np
import pytest

from creference_bayes.bench.runner import write_scenes
from creference_bayes.cli.main import main
from creference_bayes.workflows.batch import (BatchSettings, derive_seed, discover_scenes, run_batch,
                                              run_scene)
from creference_bayes.workflows.batch.engines import LocalEngine

#: Small sampler settings: the tests are about the batch, not the posterior's precision.
SMALL = BatchSettings(seed=5, sampling={"n_ensembles": 2, "n_walkers": 16, "tau_multiple": 20, "min_ess": 100})
INVALID = {"format": "creference-scene/1", "image": {"width": 640}, "target": {}}


def _numbers(result: dict) -> dict:
    """Every number a user reads from a result (not the timings)."""
    post = result["posterior"]
    return {"map": result["map"], "mean": post["mean"], "sd": post["sd"], "hdi": post["hdi"],
            "draws": post["draws"], "diagnostics": {k: v for k, v in result["diagnostics"].items()}}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """6 simulated scenes and one invalid one, estimated once by 2 local worker processes."""
    root = tmp_path_factory.mktemp("batch")
    scenes = root / "scenes"
    write_scenes(scenes, 6, seed=11, tier="medium")
    (scenes / "broken.json").write_text(json.dumps(INVALID))
    out = root / "out"
    events = []
    report = run_batch([scenes], out, LocalEngine(2), SMALL,
                       on_event=lambda key, status: events.append((key, status)))
    return {"scenes": scenes, "out": out, "report": report, "events": events}


def _result(out, key):
    return json.loads((out / "results" / f"{key}.json").read_text())


def test_batch_estimates_valid_scenes_and_records_the_invalid_one(dataset):
    out, report = dataset["out"], dataset["report"]
    keys = [f"scene_{i:04d}" for i in range(6)]
    assert report.status == {"broken": "failed", **{k: "done" for k in keys}}
    assert not report.ok
    assert sorted(k for k, _ in dataset["events"]) == sorted(["broken", *keys])
    err = json.loads((out / "errors" / "broken.json").read_text())
    assert err["stage"] == "load" and "image.height" in err["error"]
    assert not (out / "results" / "broken.json").exists()
    for key in keys:
        res = _result(out, key)
        scene = json.loads((dataset["scenes"] / f"{key}.json").read_text())
        copy = json.loads((out / "scenes" / f"{key}.json").read_text())
        assert copy["target"] == scene["target"] and copy["ground_truth"] == scene["ground_truth"]
        assert res["batch"]["key"] == key and res["batch"]["scene_copy"] == f"scenes/{key}.json"
        assert res["batch"]["seed"] == derive_seed(5, res["scene_id"]["sha256"])
        assert res["batch"]["settings"] == SMALL.to_dict()
        assert res["posterior"]["n_draws"] > 0
    manifest = json.loads((out / "batch.json").read_text())
    assert [s["status"] for s in manifest["scenes"]] == ["failed"] + ["done"] * 6


def test_summary_csv_has_one_row_per_target_with_the_distance(dataset):
    out = dataset["out"]
    rows = list(csv.DictReader((out / "summary.csv").open()))
    assert [r["scene"] for r in rows] == ["broken"] + [f"scene_{i:04d}" for i in range(6)]
    assert rows[0]["status"] == "failed" and "image.height" in rows[0]["error"]
    for row in rows[1:]:
        res = _result(out, row["scene"])
        truth = json.loads((dataset["scenes"] / f"{row['scene']}.json").read_text())["ground_truth"]
        assert row["status"] == "ok" and row["converged"] in ("true", "false")
        assert float(row["map_distance_m"]) == pytest.approx(math.hypot(res["map"]["x"], res["map"]["z"]), rel=1e-5)
        lo, hi = float(row["hdi_low_m"]), float(row["hdi_high_m"])
        assert lo < float(row["mean_distance_m"]) < hi and float(row["sd_distance_m"]) > 0
        # Eq. 3 from the truth, computed here independently of the package
        err = 100 * np.linalg.norm(np.subtract([res["map"][k] for k in "xyz"], truth["location_m"])) \
            / np.linalg.norm(truth["location_m"])
        assert float(row["location_error_pct"]) == pytest.approx(err, rel=1e-4)


def test_resume_after_deleting_two_results_recomputes_exactly_those_two(dataset, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(dataset["out"], out)
    deleted = ["scene_0001", "scene_0004"]
    before = {k: _result(out, k) for k in deleted}
    for k in deleted:
        (out / "results" / f"{k}.json").unlink()
    report = run_batch([dataset["scenes"]], out, LocalEngine(2), SMALL)
    assert sorted(report.keys("done")) == deleted
    assert sorted(report.keys("skipped")) == sorted(set(f"scene_{i:04d}" for i in range(6)) - set(deleted))
    assert report.keys("failed") == ["broken"]
    for k in deleted:
        assert _numbers(_result(out, k)) == _numbers(before[k])


def test_dask_local_cluster_gives_identical_numbers(dataset, tmp_path):
    distributed = pytest.importorskip("distributed")
    from creference_bayes.workflows.batch.engines import DaskEngine

    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None) as cluster:
        report = run_batch([dataset["scenes"]], tmp_path / "dask", DaskEngine(cluster.scheduler_address),
                           SMALL)
    assert report.status == dataset["report"].status
    for key in report.keys("done"):
        assert _numbers(_result(tmp_path / "dask", key)) == _numbers(_result(dataset["out"], key))


def test_seed_follows_the_content_not_the_name_and_changes_are_recomputed(tmp_path):
    write_scenes(tmp_path / "a", 1, seed=2, tier="low")
    src = tmp_path / "a" / "scene_0000.json"
    (tmp_path / "b").mkdir()
    data = json.loads(src.read_text())
    (tmp_path / "b" / "renamed.json").write_text(json.dumps(data, indent=3))  # same content
    settings = BatchSettings(seed=1, posterior=False)
    r1 = run_batch([tmp_path / "a", tmp_path / "b"], tmp_path / "out", LocalEngine(1), settings)
    assert r1.status == {"scene_0000": "done", "renamed": "done"}
    a, b = _result(tmp_path / "out", "scene_0000"), _result(tmp_path / "out", "renamed")
    assert a["map"] == b["map"] and a["batch"]["seed"] == b["batch"]["seed"]
    data["target"]["dimensions_m"]["length"] *= 1.01  # a changed scene is recomputed …
    src.write_text(json.dumps(data))
    r2 = run_batch([tmp_path / "a", tmp_path / "b"], tmp_path / "out", LocalEngine(1), settings)
    assert r2.status == {"scene_0000": "done", "renamed": "skipped"}
    assert _result(tmp_path / "out", "scene_0000")["batch"]["seed"] != a["batch"]["seed"]
    r3 = run_batch([tmp_path / "a", tmp_path / "b"], tmp_path / "out", LocalEngine(1),
                   BatchSettings(seed=2, posterior=False))  # … and every scene when settings change
    assert r3.status == {"scene_0000": "done", "renamed": "done"}


def test_time_limit_fails_the_scene_and_the_batch_goes_on(tmp_path):
    write_scenes(tmp_path / "s", 3, seed=4, tier="low")
    t0 = time.perf_counter()
    report = run_batch([tmp_path / "s"], tmp_path / "out", LocalEngine(2), BatchSettings(), time_limit=0.2)
    assert report.keys("failed") == ["scene_0000", "scene_0001", "scene_0002"]
    err = json.loads((tmp_path / "out" / "errors" / "scene_0002.json").read_text())
    assert err["stage"] == "time limit"
    # abandoned processes are ended, not waited for: far less than three full estimates
    assert time.perf_counter() - t0 < 20


def test_run_scene_returns_an_exception_as_a_failure_record():
    from creference_bayes.bench.simulate import simulate_scene

    job = {"data": simulate_scene(np.random.default_rng(0)), "source": "x.json", "seed": 1,
           "estimate": {"model": "no-such-model", "posterior": False}}
    res = run_scene(job)
    assert res["ok"] is False and res["stage"] == "estimate"
    assert "no-such-model" in res["error"] and "Traceback" in res["traceback"]


def test_discover_scenes_keys_nested_hidden_and_collisions(tmp_path):
    (tmp_path / "d" / "sub").mkdir(parents=True)
    (tmp_path / "d" / ".hidden").mkdir()
    for p in ("d/a.json", "d/sub/b.json", "d/.hidden/c.json", "d/notes.txt", "e.json"):
        (tmp_path / p).write_text("{}")
    found = discover_scenes([tmp_path / "d", tmp_path / "e.json", tmp_path / "d" / "a.json"])
    assert [(s.key, s.path.relative_to(tmp_path).as_posix()) for s in found] == [
        ("a", "d/a.json"), ("sub/b", "d/sub/b.json"), ("e", "e.json")]
    (tmp_path / "f").mkdir()
    (tmp_path / "f" / "a.json").write_text("{}")
    with pytest.raises(ValueError, match="share the name 'a'"):
        discover_scenes([tmp_path / "d", tmp_path / "f"])
    assert discover_scenes([tmp_path / "d"], exclude=tmp_path / "d" / "sub")[-1].key == "a"
    with pytest.raises(ValueError, match="no scene files"):
        discover_scenes([tmp_path / "f"], exclude=tmp_path / "f")


def test_derive_seed_depends_on_base_seed_and_content_only():
    assert derive_seed(0, "ab") == derive_seed(0, "ab")
    assert len({derive_seed(0, "ab"), derive_seed(1, "ab"), derive_seed(0, "ac")}) == 3
    assert 0 <= derive_seed(7, "f" * 64) < 2 ** 60


def test_cli_batch_exit_status_and_summary_line(tmp_path, capsys):
    write_scenes(tmp_path / "s", 1, seed=6, tier="low")
    out = tmp_path / "out"
    assert main(["batch", str(tmp_path / "s"), "--out", str(out), "--workers", "1", "--no-posterior"]) == 0
    assert "1 scene: 1 estimated, 0 failed" in capsys.readouterr().out
    (tmp_path / "s" / "zz_bad.json").write_text("{not json")
    assert main(["batch", str(tmp_path / "s"), "--out", str(out), "--workers", "1", "--no-posterior"]) == 1
    captured = capsys.readouterr()
    assert "2 scenes: 0 estimated, 1 already done, 1 failed" in captured.out
    assert f"zz_bad: SceneError: {tmp_path / 's' / 'zz_bad.json'}: not valid JSON" in captured.err
    assert main(["batch", str(tmp_path / "nothing"), "--out", str(out)]) == 2
    assert main(["batch", str(tmp_path / "s"), "--out", str(out), "--workers", "0"]) == 2
    assert main(["batch", str(tmp_path / "s"), "--out", str(out), "--scheduler", "tcp://x:1",
                 "--workers", "2"]) == 2


def test_the_location_prior_is_a_setting_a_resume_compares():
    # a batch started with one location prior and resumed with another must not mix the two
    flat, auto = BatchSettings(location_prior="flat"), BatchSettings()
    assert flat.to_dict() != auto.to_dict()
    assert flat.estimate_kwargs()["location_prior"] == "flat"
    assert flat.frame_dict() != auto.frame_dict()  # frames too: log-depth by default, flat on request
    assert (flat.frame_kwargs()["location_prior"], auto.frame_kwargs()["location_prior"]) == ("flat", "log-depth")
