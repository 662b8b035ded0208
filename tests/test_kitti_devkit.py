"""Our KITTI evaluation against the official devkit's compiled C++ evaluator (slow; skipped unless
``CREFERENCE_KITTI_DEVKIT`` names the compiled ``evaluate_object_3d_offline``; Car at IoU 0.5 too
when ``CREFERENCE_KITTI_DEVKIT_CAR05`` names the variant built with 0.5). How to build them:
examples/check_kitti_devkit.py and docs/evaluation.md. The ground truth is synthetic (no KITTI files)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DEVKIT = os.environ.get("CREFERENCE_KITTI_DEVKIT")
CAR05 = os.environ.get("CREFERENCE_KITTI_DEVKIT_CAR05")


@pytest.mark.slow
@pytest.mark.skipif(not (DEVKIT and Path(DEVKIT).is_file()), reason="CREFERENCE_KITTI_DEVKIT: no compiled devkit")
@pytest.mark.parametrize("seed", [0, 1])
def test_ap_agrees_with_the_official_devkit_within_a_tenth(seed, tmp_path):
    cmd = [sys.executable, str(ROOT / "examples" / "check_kitti_devkit.py"), "--devkit", DEVKIT,
           "--synthetic", "150", "--seed", str(seed), "--workdir", str(tmp_path)]
    if CAR05 and Path(CAR05).is_file():
        cmd += ["--devkit-car05", CAR05]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-2000:]
    assert "agree" in proc.stdout.splitlines()[-1]
