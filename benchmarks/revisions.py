"""The code at another git revision, installed apart, for benchmarks that compare against it.

Installed, not run from a worktree: with PYTHONPATH=worktree, ``sagfree`` came from the worktree but
its subpackages (folders beside sagfree/ in the source tree) from the editable install of this
checkout, so "before" mixed the two revisions' code.
"""
from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


@contextlib.contextmanager
def installed_revision(revision: str):
    """Yield the folder into which pip installed the code at git ``revision`` (from a temporary
    worktree; both removed afterwards, also on SIGTERM, and by the next run after a SIGKILL), or None
    outside a git checkout, for an empty revision, or where pip cannot install it (the reason
    printed)."""
    if not revision or not (ROOT / ".git").exists():
        yield None
        return
    _remove_abandoned_worktrees()
    with tempfile.TemporaryDirectory(prefix=_PREFIX) as where, _terminate_cleanly():
        checkout, site = Path(where) / "src", Path(where) / "site"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "-q", "--lock", "--reason",
                        f"{_LOCK}{os.getpid()}", str(checkout), revision], check=True)
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
            _remove_worktree(checkout)


#: the temporary folders of the installs, and the lock reason of their worktrees (+ the process id)
_PREFIX, _LOCK = "sagfree-before-", "sagfree benchmark, process "


def _remove_worktree(checkout: Path) -> None:
    # locked: --force twice
    subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", "--force", str(checkout)], check=False)


def _remove_abandoned_worktrees() -> None:
    """Remove the worktrees (and temporary folders) of earlier runs that were killed before their
    clean-up (SIGKILL, a closed terminal): their lock names a process that no longer runs."""
    listing = subprocess.run(["git", "-C", str(ROOT), "worktree", "list", "--porcelain"], capture_output=True,
                             text=True).stdout
    for entry in listing.split("\n\n"):
        fields = dict(line.split(" ", 1) for line in entry.splitlines() if " " in line)
        path, lock = Path(fields.get("worktree", "")), fields.get("locked", "")
        if lock.startswith(_LOCK) and path.parent.name.startswith(_PREFIX) and not _running(int(lock[len(_LOCK):])):
            _remove_worktree(path)
            shutil.rmtree(path.parent, ignore_errors=True)
    subprocess.run(["git", "-C", str(ROOT), "worktree", "prune"], check=False)


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, another user's
        pass
    return True


@contextlib.contextmanager
def _terminate_cleanly():
    """SIGTERM (``kill``, a CI timeout) raises SystemExit inside, so the clean-up above runs."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, lambda number, frame: sys.exit(128 + number))
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


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
