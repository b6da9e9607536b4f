"""The house's size rules, held: no module over 600 lines, no function over 80 without a
stated reason (a ``# long: <why>`` comment right above it). ``vendor/`` is not ours."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "toolkit"
MAX_MODULE_LINES = 600
MAX_FUNCTION_LINES = 80


def _modules() -> list[Path]:
    return sorted(p for p in PACKAGE.rglob("*.py") if "vendor" not in p.parts)


def test_no_module_is_over_600_lines() -> None:
    sizes = {p: len(p.read_text(encoding="utf-8").splitlines()) for p in _modules()}
    assert len(sizes) > 100  # the package was found
    assert {str(p.relative_to(PACKAGE)): n for p, n in sizes.items() if n > MAX_MODULE_LINES} == {}


def _long_functions(source: str) -> list[tuple[str, int]]:
    """(name, lines) of the functions over the limit without a ``# long:`` reason."""
    lines = source.splitlines()
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            assert node.end_lineno is not None
            length = node.end_lineno - node.lineno + 1
            first = node.decorator_list[0].lineno if node.decorator_list else node.lineno
            above = lines[first - 2].strip() if first >= 2 else ""
            if length > MAX_FUNCTION_LINES and not above.startswith("# long:"):
                found.append((node.name, length))
    return found


def test_the_function_rule_sees_a_long_function_and_its_reason() -> None:
    body = "".join(f"    x{i} = {i}\n" for i in range(MAX_FUNCTION_LINES))
    assert _long_functions(f"def f() -> None:\n{body}") == [("f", MAX_FUNCTION_LINES + 1)]
    assert _long_functions(f"# long: one table, read whole\ndef f() -> None:\n{body}") == []
    assert _long_functions(f"def f() -> None:\n{body[: -len(body.splitlines()[-1]) - 1]}") == []


def test_no_function_is_over_80_lines_without_a_reason() -> None:
    long = {
        f"{p.relative_to(PACKAGE)}:{name}": n
        for p in _modules()
        for name, n in _long_functions(p.read_text(encoding="utf-8"))
    }
    assert long == {}


def _import_graph() -> dict[str, set[str]]:
    """Module -> the package's modules it imports, every import statement counted: at the
    top, inside functions and for type checking only (a circle of type-only imports still
    ties the modules into one unit a reader must take in whole)."""
    root = PACKAGE.parent

    def name_of(path: Path) -> str:
        parts = list(path.relative_to(root).with_suffix("").parts)
        return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)

    files = {name_of(p): p for p in PACKAGE.rglob("*.py")}
    graph: dict[str, set[str]] = {m: set() for m in files}
    for module, path in files.items():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                graph[module] |= {node.module} & files.keys()
                graph[module] |= {f"{node.module}.{a.name}" for a in node.names} & files.keys()
            elif isinstance(node, ast.Import):
                graph[module] |= {a.name for a in node.names} & files.keys()
        graph[module].discard(module)
    return graph


def _circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_modules_import_each_other_not_even_for_types() -> None:
    """No import circle in the package (issue 37: sim/world.py and the three modules split
    from it imported one another, the others for WorldParams' type)."""
    assert _circles(_import_graph()) == []
    # The rule sees a circle: two toy modules that import each other.
    assert _circles({"a": {"b"}, "b": {"a"}, "c": {"a"}}) == [["a", "b"]]


def _layers_contract() -> list[str]:
    """pyproject's layers contract: each layer ("a : b" or "a | b"), top first."""
    import tomllib

    pyproject = tomllib.loads((PACKAGE.parent / "pyproject.toml").read_text(encoding="utf-8"))
    contracts = pyproject["tool"]["importlinter"]["contracts"]
    (layers,) = [c["layers"] for c in contracts if c["id"] == "layers"]
    return [" ".join(layer.split()) for layer in layers]


def test_every_module_of_the_package_sits_in_one_named_layer() -> None:
    # A new top-level module outside the contract would escape every layer rule unseen.
    placed = [m.strip() for layer in _layers_contract() for m in layer.replace("|", ":").split(":")]
    assert len(placed) == len(set(placed))
    tops = {p.stem for p in PACKAGE.glob("*.py")} | {
        p.parent.name for p in PACKAGE.glob("*/__init__.py")
    }
    assert tops - {"__init__", "__main__"} == set(placed)


def test_the_architecture_page_draws_the_layers_the_contract_checks() -> None:
    # docs/architecture.md draws each layer on one line, "name  a : b : c" (or "a | b"),
    # and says what it holds on indented lines under it.
    page = (PACKAGE.parent / "docs" / "architecture.md").read_text(encoding="utf-8")
    drawing = page.split("```\n", 2)[1].split("\n```", 1)[0]
    drawn = [
        " ".join(line.split()[1:])
        for line in drawing.splitlines()
        if line and not line.startswith(" ")
    ]
    assert drawn == _layers_contract()
