"""The docs' Python snippets run as printed, copied into a script (the way a user runs them)."""

import re
import subprocess
import sys
from pathlib import Path

from creference_bayes.cli.main import main

DOCS = Path(__file__).resolve().parents[1] / "docs"


def python_blocks(name: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", (DOCS / name).read_text(encoding="utf-8"), flags=re.S)


def test_the_batch_snippet_runs_as_a_script(tmp_path):
    """docs/batch.md's snippet, saved as a script and run with a fresh interpreter: the local
    engine's worker processes import the script again, so without its ``__main__`` guard every
    scene is lost and the script fails."""
    (block,) = python_blocks("batch.md")
    assert main(["simulate", str(tmp_path / "scenes"), "--n", "2", "--quiet"]) == 0
    script = tmp_path / "run_batch.py"
    script.write_text(block, encoding="utf-8")
    done = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "Traceback" not in done.stderr
    assert done.stdout.startswith("[]")  # report.keys("failed"): none failed
    assert len(list((tmp_path / "batch" / "results").glob("*.json"))) == 2
