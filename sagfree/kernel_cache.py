"""numba's on-disk cache of sagfree's kernels, invalidated when a module they use changes.

numba caches a compiled function (``@numba.njit(cache=True)``) under a stamp of its own source
file only, but the machine code it stores contains every kernel the function calls from other
files: after an edit of ``linalg/cholesky.py`` the cached Gauss-Newton loop (solvers/gauss_newton.py)
would go on factoring with the old code, silently, in an editable install or any checkout whose
``__pycache__`` survives a pull. Here every numba cache locator gets a stamp that adds a digest of
the contents of the package modules the function's file imports, directly or not (``dependency_digest``);
an edit anywhere in that closure makes numba recompile the function on its next call. Module-level
constants the kernels freeze in (tolerances, band widths) are covered the same way.

The closure is read from the import statements of modules already imported when the
function is decorated (imports at module level, which kernels can only use); an import made later,
inside a function, is not followed. Cost: a few ms at ``import sagfree`` (reading and hashing the
package's modules once per process). ``register`` hooks the stamp into numba's locators (a private
list, ``CacheImpl._locator_classes``); with a numba that lacks it, its own per-file stamp stays.
"""
from __future__ import annotations

import functools
import hashlib
import importlib.util
import re
import sys

from numba.core import caching

#: import statements (a parenthesized name list may span lines; backslash continuations are not read)
_IMPORT = re.compile(r"^[ \t]*import[ \t]+([\w., \t]+)", re.MULTILINE)
_FROM_IMPORT = re.compile(r"^[ \t]*from[ \t]+(\.*[\w.]*)[ \t]+import[ \t]+(\([^)]*\)|[^\n#]*)", re.MULTILINE)
#: top-level package names whose kernels get the dependency stamp
_PACKAGES: set[str] = set()


def register(*packages: str) -> None:
    """Give the kernels of ``packages`` (top-level names) the dependency stamp of the module docstring."""
    _PACKAGES.update(packages)
    owner = getattr(caching, "CacheImpl", None) or getattr(caching, "_CacheImpl", None)
    classes = getattr(owner, "_locator_classes", None)
    if classes is None or any(issubclass(cls, _DependencyStamp) for cls in classes):
        return
    classes[:] = [type(cls.__name__, (_DependencyStamp, cls), {}) for cls in classes]


class _DependencyStamp:
    """A numba cache locator mixin: the locator's own source stamp plus ``dependency_digest`` of the
    function's module, for modules of the registered packages."""

    def __init__(self, py_func, py_file):
        super().__init__(py_func, py_file)
        self._sagfree_module = getattr(py_func, "__module__", None)

    def get_source_stamp(self):
        stamp = super().get_source_stamp()
        module = self._sagfree_module
        if module is None or module.split(".")[0] not in _PACKAGES:
            return stamp
        return stamp, dependency_digest(module)


def dependency_digest(module: str) -> str:
    """SHA-256 over the contents of ``module``'s file and of every registered-package module it
    imports, directly or through others (``imported_modules``), in name order."""
    digest = hashlib.sha256()
    for name in sorted(_closure(module)):
        digest.update(name.encode())
        digest.update(_content_hash(sys.modules[name].__file__))
    return digest.hexdigest()


def _closure(module: str) -> set[str]:
    seen, stack = set(), [module]
    while stack:
        name = stack.pop()
        if name in seen:
            continue
        seen.add(name)
        stack.extend(imported_modules(name) - seen)
    return seen


@functools.lru_cache(maxsize=None)
def imported_modules(module: str) -> frozenset[str]:
    """The registered-package modules that ``module``'s source imports and this process has loaded
    (for ``from x import y``: x.y where that is a module, else x: a package's ``__init__`` counts
    only for the names taken from it)."""
    path = getattr(sys.modules.get(module), "__file__", None)
    if path is None:
        return frozenset()
    package = sys.modules[module].__package__ or ""
    with open(path, encoding="utf-8") as f:
        source = f.read()
    names = set()
    for match in _IMPORT.finditer(source):
        names.update(name.split(" as ")[0].strip() for name in match.group(1).split(","))
    for match in _FROM_IMPORT.finditer(source):
        try:
            base = importlib.util.resolve_name(match.group(1), package)
        except ImportError:
            continue
        for alias in match.group(2).strip("()").split(","):  # the submodule where the name is one, else the module
            alias = alias.split("#")[0].split(" as ")[0].strip()
            names.add(f"{base}.{alias}" if _loaded(f"{base}.{alias}") else base)
    return frozenset(name for name in names if name.split(".")[0] in _PACKAGES and name != module and _loaded(name))


def _loaded(name: str) -> bool:
    return getattr(sys.modules.get(name), "__file__", None) is not None


@functools.lru_cache(maxsize=None)
def _content_hash(path: str) -> bytes:
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).digest()
