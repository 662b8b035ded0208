"""Every example script takes --help, and writes nothing when it does."""

import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = sorted((Path(__file__).resolve().parents[1] / "examples").glob("*.py"))


def test_there_are_examples():
    assert len(EXAMPLES) >= 5


@pytest.mark.parametrize("script", EXAMPLES, ids=lambda p: p.name)
def test_example_help(script, tmp_path):
    proc = subprocess.run([sys.executable, str(script), "--help"], capture_output=True, text=True,
                          timeout=120, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("usage:")
    assert proc.stderr == ""
    assert list(tmp_path.iterdir()) == []  # --help writes nothing


def test_no_example_writes_into_docs_by_default():
    for script in EXAMPLES:
        text = script.read_text()
        assert 'default="docs' not in text and "default='docs" not in text, script.name
