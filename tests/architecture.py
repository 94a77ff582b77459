"""espdock's import graph, read with ast from the source tree: cycles, upward imports, sizes.

Every `import espdock...` and `from espdock... import ...` counts, at module level or inside a
function (a deferred import still ties the two modules together). `python -m tests.architecture`
prints the numbers; tests/unit/test_architecture.py asserts them.
"""

from __future__ import annotations

import ast
import fnmatch
import sys
from collections import Counter
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "espdock"

# Lowest first. A module may import its own layer or a lower one, never a higher one.
# The build core is a plan's vocabulary (image specs, the steps, the plan; the stamps): pure
# data, below everything that plans or runs it. images/ runs keyed images and containers on the
# engine; ros/ and firmware/ plan and run their own steps on top of that; build/'s runner
# dispatches a plan's steps to them and its plan puts both worlds' steps together; the CLI
# parses and calls. ros and firmware share a layer and may not import each other: where a
# firmware package meets ROS (its install into ws/install, the micro-ROS image's interface
# packages) the build core's data carries it.
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    (
        "shared",
        (
            "espdock",
            "espdock.errors",
            "espdock.events",
            "espdock.layout",
            "espdock.config",
            "espdock.workspace",
            "espdock.defaults",
            "espdock.durable",
            "espdock.interrupts",
            "espdock.scratch",
            "espdock.downloads",
        ),
    ),
    ("build core", ("espdock.build", "espdock.build.steps", "espdock.build.stamps")),
    ("images", ("espdock.images", "espdock.images.*")),
    ("ros", ("espdock.ros", "espdock.ros.*")),
    ("firmware", ("espdock.firmware", "espdock.firmware.*")),
    ("build", ("espdock.build.*",)),
    ("cli", ("espdock.cli", "espdock.cli.*", "espdock.__main__")),
)
# Same rank: neither may import the other.
PEERS = {"ros": "worlds", "firmware": "worlds"}


def modules(root: Path = PACKAGE) -> dict[str, Path]:
    """Every module under ROOT by dotted name (a package by its __init__)."""
    found = {}
    for path in sorted(root.rglob("*.py")):
        parts = list(path.relative_to(root.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        found[".".join(parts)] = path
    return found


def _target(name: str, known: dict[str, Path]) -> str | None:
    while name and name not in known:
        name = name.rpartition(".")[0]
    return name or None


def import_graph(root: Path = PACKAGE) -> dict[str, set[str]]:
    """Module -> the espdock modules it imports anywhere in its body."""
    known = modules(root)
    graph: dict[str, set[str]] = {name: set() for name in known}
    for name, path in known.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")[: len(package.split(".")) - node.level + 1]
                    source = ".".join([*base, node.module] if node.module else base)
                else:
                    source = node.module or ""
                # `from espdock.ros import nodes` imports the module espdock.ros.nodes.
                targets = [f"{source}.{alias.name}" for alias in node.names]
            for target in targets:
                if target.split(".")[0] != root.name:
                    continue
                resolved = _target(target, known)
                if resolved and resolved != name:
                    graph[name].add(resolved)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in sorted(graph[node]):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10 * len(graph)))
    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def layer(module: str) -> str:
    """The first layer (lowest first) with a pattern that names MODULE."""
    for name, patterns in LAYERS:
        if any(fnmatch.fnmatchcase(module, pattern) for pattern in patterns):
            return name
    raise LookupError(f"{module} is in no layer of tests/architecture.py")


def upward(graph: dict[str, set[str]]) -> list[tuple[str, str]]:
    """Imports from a module to one of a higher layer, or across the two worlds."""
    rank = {name: i for i, (name, _) in enumerate(LAYERS)}
    for name in PEERS:
        rank[name] = min(rank[peer] for peer in PEERS if PEERS[peer] == PEERS[name])
    bad = []
    for source, targets in sorted(graph.items()):
        for target in sorted(targets):
            here, there = layer(source), layer(target)
            if rank[there] > rank[here] or (here != there and rank[there] == rank[here]):
                bad.append((source, target))
    return bad


def largest_class(path: Path) -> tuple[str, int]:
    best = ("", 0)
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ClassDef):
            size = (node.end_lineno or node.lineno) - node.lineno + 1
            best = max(best, (node.name, size), key=lambda pair: pair[1])
    return best


def report(root: Path = PACKAGE) -> str:
    known = modules(root)
    graph = import_graph(root)
    # Per folder, its modules without the package's own __init__.
    folders = Counter(name.rpartition(".")[0] for name, path in known.items() if path.name != "__init__.py")
    lines = [f"modules (without __init__): {sum(folders.values())}"]
    lines += [f"  {folder.replace('.', '/')}/: {count}" for folder, count in sorted(folders.items())]
    sizes = {name: len(path.read_text().splitlines()) for name, path in known.items()}
    biggest = max(sizes, key=sizes.__getitem__)
    lines.append(f"largest module: {biggest} {sizes[biggest]} lines")
    classes = {name: largest_class(path) for name, path in known.items()}
    owner = max(classes, key=lambda n: classes[n][1])
    lines.append(f"largest class: {owner}.{classes[owner][0]} {classes[owner][1]} lines")
    found = cycles(graph)
    lines.append(f"import cycles (SCCs > 1 module): {len(found)}")
    lines += [f"  {' '.join(component)}" for component in found]
    try:
        bad = upward(graph)
    except LookupError as error:
        lines.append(f"upward imports: ? ({error})")
    else:
        lines.append(f"upward imports: {len(bad)}")
        lines += [f"  {source} -> {target}" for source, target in bad]
    return "\n".join(lines)


if __name__ == "__main__":
    print(report(Path(sys.argv[1]).resolve() if len(sys.argv) > 1 else PACKAGE))
