"""Every example script takes --help, and writes nothing when it does."""

import subprocess
import sys
from pathlib import Path

EXAMPLES = sorted((Path(__file__).resolve().parents[1] / "examples").glob("*.py"))


def test_there_are_examples():
    assert len(EXAMPLES) >= 5


def test_every_example_takes_help_and_writes_nothing(tmp_path):
    runs = {}
    for script in EXAMPLES:  # all at once: each pays its own imports
        cwd = tmp_path / script.stem
        cwd.mkdir()
        runs[script.name] = (cwd, subprocess.Popen([sys.executable, str(script), "--help"], cwd=cwd,
                                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
    for name, (cwd, proc) in runs.items():
        out, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, f"{name}: {err}"
        assert out.startswith("usage:"), name
        assert err == "", name
        assert list(cwd.iterdir()) == [], f"{name} --help wrote files"


def test_no_example_writes_into_docs_by_default():
    for script in EXAMPLES:
        text = script.read_text()
        assert 'default="docs' not in text and "default='docs" not in text, script.name
