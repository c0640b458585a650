"""The layers only look down (ARCHITECTURE.md): engine <- priors <- problems <- app.

Walks every import statement of the project's modules (function-level ones included,
read from the source, nothing imported) and fails on an import of a higher layer and on
a cycle between modules."""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("motionopt", "priors", "problems")
#: Layer of a module by its name's prefix; the longest matching prefix wins.
LAYERS = {"motionopt": 0, "priors": 1, "problems": 2, "motionopt.app": 3,
          "motionopt.__main__": 3}  # ``python -m motionopt`` starts the command line
LAYER_NAMES = {0: "engine (motionopt)", 1: "priors", 2: "problems", 3: "app (motionopt.app)"}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def layer(module: str) -> int:
    best = max((p for p in LAYERS if module == p or module.startswith(p + ".")), key=len)
    return LAYERS[best]


def imports_of(path: Path, modules: set[str]) -> list[tuple[int, str]]:
    """(line, module) of every import of a project module in the file."""
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(up + ([base] if base else []))
            # "from pkg import mod" imports the module pkg.mod when there is one
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
        else:
            continue
        for t in targets:
            while t and t not in modules:
                t = t.rpartition(".")[0]
            if t and t != name:
                found.append((node.lineno, t))
    return found


def graph() -> dict[str, list[tuple[int, str]]]:
    files = [p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")]
    modules = {module_name(p) for p in files}
    return {module_name(p): imports_of(p, modules) for p in files}


def test_the_walk_sees_the_project():
    g = graph()
    assert {"motionopt.objective", "priors.ccnet", "problems.denoise", "motionopt.app.cli"} <= g.keys()
    assert (any(t == "motionopt.objective" for _, t in g["problems.common"])
            and any(t.startswith("problems") for _, t in g["motionopt.app.demo"]))


def test_no_module_imports_a_higher_layer():
    upward = [f"{m} (line {line}) imports {t}: {LAYER_NAMES[layer(m)]} may not import {LAYER_NAMES[layer(t)]}"
              for m, edges in graph().items() for line, t in edges if layer(t) > layer(m)]
    assert not upward, "\n".join(upward)


def test_no_import_cycles():
    g = {m: sorted({t for _, t in edges}) for m, edges in graph().items()}
    state: dict[str, int] = {}
    cycles: list[str] = []

    def visit(m: str, stack: list[str]) -> None:
        state[m] = 1
        for t in g.get(m, []):
            # a package's __init__ importing its own submodules is how packages export names
            if t.startswith(m + "."):
                continue
            if state.get(t) == 1:
                cycles.append(" -> ".join(stack[stack.index(t):] + [t]))
            elif t not in state:
                visit(t, stack + [t])
        state[m] = 2

    for m in sorted(g):
        if m not in state:
            visit(m, [m])
    assert not cycles, "import cycles:\n" + "\n".join(cycles)
