"""Compiled kernels call each other with typed arguments, never with integer or boolean constants.

numba types a constant argument of a call between njit functions as a literal (``Literal[int](0)``,
``Literal[bool](True)``, also inside a tuple), and compiles the callee once per literal value: a
second specialization of its whole call tree, optimized and emitted again on a machine's first run
(confirmed_at was compiled three times, for 0, for CORRECTIONS and for an integer, 19 s of the
warm-up's 173 s; benchmarks/RESULTS.md). A constant is passed as ``np.int64(...)`` or
``np.bool_(...)``, which numba types as a plain integer or boolean. This test reads the sources: in
every njit function, each call of another njit function of the package, whose arguments must not
be an int or bool constant, an expression of constants, an ALL_CAPS module constant bound to one,
a local assigned once to one, or a tuple holding any of these.
"""
import ast
from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = sorted({ROOT / folder for folder in
                  tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"].values()})


def _modules():
    for folder in FOLDERS:
        for path in sorted(folder.rglob("*.py")):
            if "__pycache__" not in path.parts:
                yield path, ast.parse(path.read_text(), filename=str(path))


def _is_njit(function: ast.FunctionDef) -> bool:
    for decorator in function.decorator_list:
        target = decorator.func if isinstance(decorator, ast.Call) else decorator
        name = target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", "")
        if name == "njit":
            return True
    return False


def _integer_constant(node: ast.AST, names: set[str]) -> bool:
    """Whether numba types ``node`` as an integer or boolean literal (``names``: those bound to one)."""
    if isinstance(node, ast.Constant):
        return isinstance(node.value, (bool, int))
    if isinstance(node, ast.Name):
        return node.id in names
    if isinstance(node, ast.UnaryOp):
        return _integer_constant(node.operand, names)
    if isinstance(node, ast.BinOp):
        return _integer_constant(node.left, names) and _integer_constant(node.right, names)
    if isinstance(node, ast.Tuple):
        return any(_integer_constant(element, names) for element in node.elts)
    return False


def _module_constants(tree: ast.Module) -> set[str]:
    names = set()
    for node in tree.body:
        if isinstance(node, (ast.Assign, ast.AnnAssign)) and node.value is not None:
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for target in targets:
                if isinstance(target, ast.Name) and target.id.isupper() and _integer_constant(node.value, set()):
                    names.add(target.id)
    return names


def _local_constants(function: ast.FunctionDef, constants: set[str]) -> set[str]:
    """Locals of ``function`` assigned exactly once, to an integer or boolean constant."""
    assigned: dict[str, list[ast.AST | None]] = {}
    for node in ast.walk(function):
        if isinstance(node, ast.Assign):
            for target in node.targets:
                for name in ast.walk(target):
                    if isinstance(name, ast.Name):
                        value = node.value if isinstance(target, ast.Name) else None
                        assigned.setdefault(name.id, []).append(value)
        elif isinstance(node, (ast.AugAssign, ast.AnnAssign, ast.For, ast.comprehension, ast.NamedExpr)):
            for name in ast.walk(node.target):
                if isinstance(name, ast.Name):
                    assigned.setdefault(name.id, []).append(None)
    return {name for name, values in assigned.items()
            if len(values) == 1 and values[0] is not None and _integer_constant(values[0], constants)}


def _callee(call: ast.Call) -> str:
    return call.func.attr if isinstance(call.func, ast.Attribute) else getattr(call.func, "id", "")


def test_no_kernel_calls_another_with_an_integer_or_boolean_constant():
    modules = list(_modules())
    kernels, constants = set(), set()
    for _, tree in modules:
        constants |= _module_constants(tree)
        kernels |= {node.name for node in ast.walk(tree) if isinstance(node, ast.FunctionDef) and _is_njit(node)}
    assert {"confirmed_at", "_mprgp", "_nelder_mead_round"} <= kernels and "CORRECTIONS" in constants
    found = []
    for path, tree in modules:
        for function in (node for node in ast.walk(tree) if isinstance(node, ast.FunctionDef) and _is_njit(node)):
            names = constants | _local_constants(function, constants)
            for call in (node for node in ast.walk(function) if isinstance(node, ast.Call)):
                if _callee(call) not in kernels:
                    continue
                for position, argument in enumerate([*call.args, *(k.value for k in call.keywords)]):
                    if _integer_constant(argument, names):
                        found.append(f"{path.relative_to(ROOT)}:{call.lineno}: {function.name} calls "
                                     f"{_callee(call)} with the constant {ast.unparse(argument)} "
                                     f"(argument {position + 1}): pass np.int64(...) or np.bool_(...)")
    assert not found, "\n".join(found)
