"""The code at another git revision, installed apart, for benchmarks that compare against it.

Installed, not run from a worktree: with PYTHONPATH=worktree, ``sagfree`` came from the worktree but
its subpackages (folders beside sagfree/ in the source tree) from the editable install of this
checkout, so "before" mixed the two revisions' code.
"""
from __future__ import annotations

import contextlib
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


@contextlib.contextmanager
def installed_revision(revision: str):
    """Yield the folder into which pip installed the code at git ``revision`` (from a temporary
    worktree; both removed afterwards), or None outside a git checkout, for an empty revision, or
    where pip cannot install it (the reason printed)."""
    if not revision or not (ROOT / ".git").exists():
        yield None
        return
    with tempfile.TemporaryDirectory(prefix="sagfree-before-") as where:
        checkout, site = Path(where) / "src", Path(where) / "site"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-q", str(checkout), revision],
                       check=True)
        try:
            installed = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target",
                                        str(site), str(checkout)], capture_output=True, text=True)
            if installed.returncode != 0:  # e.g. no network for pip's build isolation
                reason = (installed.stderr.strip().splitlines() or ["no message"])[-1]
                print(f"(pip could not install {revision}: {reason})")
                yield None
            else:
                yield site
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(checkout)], check=False)


#: ``import sagfree``, ``from sagfree ...`` and ``sagfree.<module>`` in code: what ``renamed_copy``
#: rewrites (not "sagfree-demo", "sagfree:" primvars or paths such as ~/.cache/sagfree)
_REFERENCE = re.compile(r"\b(import|from) sagfree\b|\bsagfree(?=\.[A-Za-z_])")


def renamed_copy(site: Path, name: str, into: Path) -> Path:
    """Copy the ``sagfree`` package installed in ``site`` to ``into``/``name`` with its imports
    rewritten to ``name``, so that one process can import both codes; returns ``into``, the folder
    to put on sys.path. The copy compiles its numba kernels afresh (its own cache)."""
    target = into / name
    shutil.copytree(site / "sagfree", target, ignore=shutil.ignore_patterns("__pycache__"))
    for path in target.rglob("*.py"):
        text = path.read_text()
        path.write_text(_REFERENCE.sub(lambda m: f"{m.group(1)} {name}" if m.group(1) else name, text))
    return into
