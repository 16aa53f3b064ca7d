"""The package's layout: subpackages by pipeline stage, data flowing one way, no import cycle."""

import ast
from pathlib import Path

import cfsig

PACKAGE = Path(cfsig.__file__).parent
# The stages a mesh goes through, in order; a module may import from its own stage and earlier
# ones only. The modules at the top are shared by all (errors, params, isolate) or drive the
# stages (batch, between the descriptors and the index; cli, last).
ORDER = {
    "errors": 0, "params": 0, "isolate": 0, "files": 1, "repair": 2, "operators": 3,
    "descriptors": 4, "index": 5, "batch": 6, "search": 7, "evaluation": 8, "figures": 9,
    "cli": 10, "__main__": 11,
}  # fmt: skip


def _stage(module: str) -> str:
    """The stage of a module named ``cfsig.<stage>...``."""
    return module.split(".")[1]


def _imports() -> dict[str, set[str]]:
    """Every module of the package and the package modules it imports, anywhere in it."""
    found = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        targets = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("cfsig"):
                targets |= {f"{node.module}.{a.name}" for a in node.names} | {node.module}
            elif isinstance(node, ast.Import):
                targets |= {a.name for a in node.names if a.name.startswith("cfsig")}
        found[name] = {t for t in targets if t != "cfsig" and not t.startswith("cfsig.__")}
    modules = set(found)
    return {m: {t for t in ts if t in modules} for m, ts in found.items()}


def test_every_module_is_in_a_stage():
    assert {_stage(m) for m in _imports() if m != "cfsig"} == set(ORDER)


def test_data_flows_one_way():
    backward = [
        (module, target)
        for module, targets in _imports().items()
        if module != "cfsig"
        for target in targets
        if ORDER[_stage(target)] > ORDER[_stage(module)]
    ]
    assert backward == []


def test_the_index_knows_no_descriptor():
    index = {m: ts for m, ts in _imports().items() if m.startswith("cfsig.index")}
    assert index and all(
        _stage(t) in ("index", "errors", "params") for ts in index.values() for t in ts
    )


def test_no_import_cycle():
    graph = {m: ts - {m} for m, ts in _imports().items() if m != "cfsig"}
    done: set[str] = set()

    def visit(module: str, path: tuple[str, ...]) -> None:
        assert module not in path, " -> ".join((*path, module))
        if module in done:
            return
        for target in graph.get(module, ()):
            if not target.startswith(module + "."):  # a package's own modules
                visit(target, (*path, module))
        done.add(module)

    for module in graph:
        visit(module, ())
