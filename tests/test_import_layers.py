"""Imports run down the layers (../ARCHITECTURE.md): no two modules of the package import each
other, directly or through others, counting imports inside functions and a package's
``__init__`` (a module that takes a name from its own package's ``__init__`` while that
``__init__`` imports it is such a circle)."""
import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "fetchbench_ms"


def _modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def _imported(module: str, path: Path, modules: dict) -> set[str]:
    """The package's modules that ``module`` imports anywhere in its text."""
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name in modules}
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            target = ".".join(base + (node.module.split(".") if node.module else []))
            for alias in node.names:  # a submodule by name, else a name of the module itself
                name = f"{target}.{alias.name}"
                if name in modules:
                    found.add(name)
                elif target in modules:
                    found.add(target)
    return found - {module}


def import_circles(edges: dict[str, set]) -> list[list[str]]:
    """The strongly connected groups of more than one module (Tarjan's algorithm, iterative)."""
    index, low, on_stack, stack, circles, counter = {}, {}, set(), [], [], 0
    for root in edges:
        if root in index:
            continue
        work = [(root, iter(sorted(edges[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(edges[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                group = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    group.append(member)
                    if member == node:
                        break
                if len(group) > 1:
                    circles.append(sorted(group))
    return circles


def test_the_circle_finder_finds_a_circle_through_a_package_face():
    edges = {"p": {"p.a"}, "p.a": {"p.b"}, "p.b": {"p"}, "p.c": {"p.a"}, "q": set()}
    assert import_circles(edges) == [["p", "p.a", "p.b"]]
    assert import_circles({"a": {"b"}, "b": set()}) == []


def test_no_module_of_the_package_imports_itself_back():
    modules = _modules()
    assert "fetchbench_ms.planning.trajopt" in modules and "fetchbench_ms.envs" in modules
    edges = {name: _imported(name, path, modules) for name, path in modules.items()}
    assert "fetchbench_ms.planning.trajopt_costs" in edges["fetchbench_ms.planning.trajopt"]
    assert import_circles(edges) == []
