"""The layout holds: layer rules (import-linter), no private names across packages, and the move of the
shared layer changed no result."""
import ast
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import sagfree

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: import-linter depends on tomli
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
PACKAGE_DIRS = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]


def source_tree(target: Path) -> Path:
    """The checkout laid out as the installed namespace (sagfree/formulation/..., as pyproject's
    package-dir maps it), so the source itself is checked whether sagfree is installed or editable."""
    for package, folder in sorted(PACKAGE_DIRS.items()):
        shutil.copytree(ROOT / folder, target.joinpath(*package.split(".")), dirs_exist_ok=True,
                        ignore=shutil.ignore_patterns("__pycache__"))
    return target


def lint_imports(tree: Path) -> subprocess.CompletedProcess:
    executable = Path(sys.executable).with_name("lint-imports")
    command = [str(executable)] if executable.exists() else [sys.executable, "-m", "importlinter.cli"]
    environment = dict(os.environ, PYTHONPATH=str(tree))
    return subprocess.run([*command, "--config", str(ROOT / "pyproject.toml"), "--no-cache"], cwd=tree,
                          env=environment, capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def tree(tmp_path_factory) -> Path:
    return source_tree(tmp_path_factory.mktemp("layout"))


def test_layer_contracts_hold(tree):
    run = lint_imports(tree)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "Contracts: 2 kept, 0 broken" in run.stdout


@pytest.mark.parametrize("module, wrong", [
    ("solvers/alm.py", "from sagfree.baselines import naive"),        # a solver importing a baseline
    ("formulation/problem.py", "from sagfree.contract import result"),  # the model importing a layer above
    ("sagfree/contract/result.py", "from sagfree.solvers import mprgp"),  # the contract importing a solver
])
def test_a_wrong_import_breaks_the_build(tmp_path, module, wrong):
    tree = source_tree(tmp_path)
    package, _, rest = module.partition("/")
    path = tree / "sagfree" / (rest if package == "sagfree" else module)
    path.write_text(path.read_text() + f"\n{wrong}  # deliberately wrong\n")
    run = lint_imports(tree)
    assert run.returncode != 0
    assert "BROKEN" in run.stdout and wrong.split()[1] in run.stdout, run.stdout


def test_no_private_name_of_another_package_outside_formulation():
    """No module outside formulation/ reaches into another package's _private names (imports or
    attributes of objects other than self/cls)."""
    offences = []
    for folder in ("sagfree", "solvers", "baselines", "reports", "scenes"):
        for path in (ROOT / folder).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text())):
                names = []
                if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("sagfree"):
                    names = [alias.name for alias in node.names]
                elif isinstance(node, ast.Attribute) and not (isinstance(node.value, ast.Name)
                                                              and node.value.id in ("self", "cls")):
                    names = [node.attr]
                offences += [f"{path.relative_to(ROOT)}:{node.lineno} {name}" for name in names
                             if name.startswith("_") and not name.startswith("__")]
    assert not offences, offences


def test_import_from_a_clone_without_installing_says_to_install(tmp_path):
    """PYTHONPATH=. from a clone finds sagfree/ without its subpackages: a clear message, not a
    circular-import error. (-S: without site-packages, as where sagfree is not installed.)"""
    shutil.copytree(ROOT / "sagfree", tmp_path / "sagfree", ignore=shutil.ignore_patterns("__pycache__"))
    run = subprocess.run([sys.executable, "-S", "-c", "import sagfree"], cwd=tmp_path, capture_output=True,
                         text=True, env=dict(os.environ, PYTHONPATH=str(tmp_path)), timeout=120)
    assert run.returncode != 0
    assert "sagfree is not installed" in run.stderr and "pip install ." in run.stderr, run.stderr


def test_default_groom_results_unchanged_by_the_layout():
    """p of groom(20, 50, seed=0) with asc equals the stored copy: a guard that moving code changes no
    result (first stored before the shared layer moved out of solvers/, bit-identical after the move;
    stored anew when the problem itself changed: the regularizer's length shares and the stability
    floors; and when asc's method did: the crawl test of its inner solves, Newton-SQP after one
    crawling round, stiffness floors checked by restiffening, the start at the optimum of a root-held
    strand, floors checked where the re-solve lands). The tolerance is 1e-6 of the largest
    entry: p is reproducible only to the rounding of what leads to it, and another CPU's BLAS kernels
    (numpy's stacked products, numba's dot products) round differently: the strands' points moved
    by 4e-16 (relative) moved p by up to 2.6e-8 of the largest entry in three trials (a 1e-12 guard
    failed on such a change). A change of method moves p by the solver's tolerance, 1e-5."""
    stored = np.load(ROOT / "tests" / "data" / "groom_20_50_seed0_asc.npz")
    results = sagfree.optimize(sagfree.scenes.groom(20, 50, seed=0), solver="asc", jobs=1)
    assert [r.status for r in results] == list(stored["status"])
    p = np.stack([r.p for r in results])
    assert np.allclose(p, stored["p"], rtol=0.0, atol=1e-6 * np.abs(stored["p"]).max())
