"""The readers' modules import one way (no cycle, lazy imports included), and every storage format of the table is
recognised by its first bytes. That they use only each other's public names is the project-wide rule of
tests/test_private_names.py."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from slamobs.pipeline.readers import container

READERS = Path(container.__file__).resolve().parent
PACKAGE = "slamobs.pipeline.readers"


def _imports() -> dict[str, list[tuple[str, str, int]]]:
    """Module -> (readers module imported, name imported from it, line), every import statement anywhere."""
    found: dict[str, list[tuple[str, str, int]]] = {}
    for path in sorted(READERS.glob("*.py")):
        here = path.stem
        edges = found.setdefault(here, [])
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, ast.ImportFrom):
                continue
            if node.level == 1:
                base = node.module or ""
            elif node.level == 0 and (node.module or "").startswith(PACKAGE):
                base = (node.module or "")[len(PACKAGE) + 1 :]
            else:
                continue
            for alias in node.names:
                if not base and (READERS / f"{alias.name}.py").exists():  # from . import module
                    edges.append((alias.name, "", node.lineno))
                elif base:
                    edges.append((base.split(".")[0], alias.name, node.lineno))
    return found


def test_readers_modules_import_each_other_without_cycles():
    graph = {
        m: {t for t, _, _ in edges if t != m and t != "__init__"} for m, edges in _imports().items() if m != "__init__"
    }
    done: set[str] = set()

    def visit(node: str, path: list[str]) -> None:
        if node in path:
            pytest.fail("import cycle: " + " -> ".join([*path[path.index(node) :], node]))
        if node in done:
            return
        for nxt in sorted(graph.get(node, ())):
            visit(nxt, [*path, node])
        done.add(node)

    for module in sorted(graph):
        visit(module, [])


@pytest.mark.parametrize("fmt", container.FORMATS, ids=lambda f: f.kind)
def test_every_format_of_the_table_is_recognised_by_its_magic(tmp_path, fmt):
    path = tmp_path / "log.unknown-suffix"
    path.write_bytes(fmt.magic + b"\0" * 64)
    assert container.detect_container(path).kind == fmt.kind
