"""The README's Python examples run as written: its ```python blocks, one after another in one
namespace (as a reader pastes them into one session), in an empty directory."""
import re
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parent.parent / "README.md"


def python_blocks() -> list[tuple[int, str]]:
    """(line number, code) of every ```python block of the README."""
    text = README.read_text()
    return [(text[: m.start()].count("\n") + 2, m.group(1)) for m in re.finditer(r"```python\n(.*?)```", text, re.S)]


def test_the_readme_has_python_examples():
    assert len(python_blocks()) >= 2


@pytest.mark.slow
def test_every_python_example_runs_as_written(tmp_path):
    script = "\n".join(f"exec(compile({code!r}, 'README.md, the python block at line {line}', 'exec'))"
                       for line, code in python_blocks())
    run = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stderr[-3000:]
    # the files the examples say they write, and what `sagfree simulate` reads back from them
    assert (tmp_path / "groom.obj").exists() and (tmp_path / "groom.params.npz").exists()
    simulate = subprocess.run([sys.executable, "-m", "sagfree.cli", "simulate", "groom.obj", "--params",
                               "groom.params.npz", "--no-push", "--steps", "5", "--quiet", "--jobs", "2"],
                              cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert simulate.returncode == 0, simulate.stdout[-2000:] + simulate.stderr[-2000:]
    assert "200/200 strands stay within" in simulate.stdout
