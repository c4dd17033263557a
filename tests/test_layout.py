"""Unit tier: the layout rules of issue 21, read from the source (ast): no module in app/ over 500 lines, no
function over 80, run.py under 200 lines, and no import circle between app's modules (every import, at the top
or inside a function; `from P import x` counts as importing the submodule P.x when there is one)."""
import ast
import pathlib

import pytest

pytestmark = pytest.mark.unit

APP = pathlib.Path(__file__).resolve().parents[1] / "app"
SOURCES = sorted(APP.rglob("*.py"))


def test_no_module_over_500_lines_no_function_over_80_and_run_py_under_200():
    long_modules = [(str(p.relative_to(APP)), n) for p in SOURCES if (n := len(p.read_text().splitlines())) > 500]
    long_functions = [(f"{p.relative_to(APP)}:{f.lineno} {f.name}", f.end_lineno - f.lineno + 1)
                      for p in SOURCES for f in ast.walk(ast.parse(p.read_text()))
                      if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef)) and f.end_lineno - f.lineno >= 80]
    assert not long_modules and not long_functions, (long_modules, long_functions)
    assert len((APP / "run.py").read_text().splitlines()) < 200


def _module_names():
    mods = {}
    for p in SOURCES:
        parts = list(p.relative_to(APP.parent).with_suffix("").parts)
        package = parts[-1] == "__init__"
        mods[".".join(parts[:-1] if package else parts)] = (p, package)
    return mods


def _imports(mods):
    def known(name):
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name
    graph = {}
    for m, (p, package) in mods.items():
        here = m if package else m.rpartition(".")[0]
        edges = set()
        for node in ast.walk(ast.parse(p.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = here.split(".")[:len(here.split(".")) - node.level + 1]
                    base = ".".join(up + ([node.module] if node.module else []))
                names = [f"{base}.{a.name}" if f"{base}.{a.name}" in mods else base for a in node.names]
            edges |= {known(n) for n in names if n.startswith("app")}
        graph[m] = edges - {m, ""}
    return graph


def test_no_import_circle():
    graph = _imports(_module_names())
    assert graph["app.run"] and "app.scene" in graph["app.run"]  # the graph holds the imports it should
    done, path, circles = set(), [], []

    def visit(m):
        if m in path:
            circles.append(path[path.index(m):] + [m])
            return
        if m in done:
            return
        path.append(m)
        for n in sorted(graph.get(m, ())):
            visit(n)
        path.pop()
        done.add(m)

    for m in sorted(graph):
        visit(m)
    assert not circles, circles
