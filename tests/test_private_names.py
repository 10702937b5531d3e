"""No module of the project uses another module's private names: the package (``pipeline/``, ``cli/``,
``schemas/``), ``tests/`` and ``benchmarks/``, read with ``ast`` (imports anywhere in a file, lazy ones too). A
name that another module needs is part of its module's interface: public, and its docstring says why; helpers
that tests share live in a helper module of ``tests/`` under public names (``tests/batch_checks.py``)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "slamobs"
#: The folders installed as subpackages of ``slamobs``, and those imported by their file names (each puts its
#: own folder, or the other, on ``sys.path``).
INSTALLED, BY_FILE_NAME = ("pipeline", "cli", "schemas"), ("tests", "benchmarks")


def module_name(path: Path) -> str:
    """The name the project imports ``path`` under: ``slamobs.pipeline.lie``, or a test or benchmark's file name."""
    parts = path.relative_to(ROOT).with_suffix("").parts
    if parts[0] in BY_FILE_NAME:
        return parts[-1]
    return ".".join([PACKAGE, *(parts[:-1] if parts[-1] == "__init__" else parts)])


def project_files() -> list[Path]:
    return [ROOT / "__init__.py"] + [
        p
        for folder in INSTALLED + BY_FILE_NAME
        for p in sorted((ROOT / folder).rglob("*.py"))
        if "__pycache__" not in p.parts
    ]


def is_private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _from_base(node: ast.ImportFrom, here: str, is_package: bool) -> str:
    """The module an ``import from`` reads (relative ones resolved against ``here``)."""
    if not node.level:
        return node.module or ""
    parts = here.split(".")
    keep = len(parts) - node.level + (1 if is_package else 0)
    return ".".join(parts[:keep] + ([node.module] if node.module else []))


def uses_of_private_names(path: Path, modules: set[str]) -> list[str]:
    """``from M import _x`` and ``M._x`` in ``path``, M another module of ``modules`` (``file:line: M._x``)."""
    here, tree = module_name(path), ast.parse(path.read_text(encoding="utf-8"))
    bound: dict[str, str] = {}  # a local name -> the project module it names (file-wide: good enough for a rule)
    found = []
    where = path.relative_to(ROOT).as_posix()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name in modules or alias.name.split(".")[0] in modules:
                    local = alias.asname or alias.name.split(".")[0]
                    bound[local] = alias.name if alias.asname else alias.name.split(".")[0]
        elif isinstance(node, ast.ImportFrom):
            base = _from_base(node, here, path.name == "__init__.py")
            if base not in modules:
                continue
            for alias in node.names:
                if is_private(alias.name) and base != here:
                    found.append(f"{where}:{node.lineno}: {base}.{alias.name}")
                elif f"{base}.{alias.name}" in modules:
                    bound[alias.asname or alias.name] = f"{base}.{alias.name}"
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and is_private(node.attr):
            target = _module_of(node.value, bound, modules)
            if target is not None and target != here:
                found.append(f"{where}:{node.lineno}: {target}.{node.attr}")
    return found


def _module_of(node: ast.expr, bound: dict[str, str], modules: set[str]) -> str | None:
    """The project module ``node`` names (``lie``, ``slamobs.pipeline.lie``), or None."""
    if isinstance(node, ast.Name):
        return bound.get(node.id)
    if isinstance(node, ast.Attribute):
        outer = _module_of(node.value, bound, modules)
        if outer is not None and f"{outer}.{node.attr}" in modules:
            return f"{outer}.{node.attr}"
    return None


def test_the_rule_sees_every_form_of_use(tmp_path, monkeypatch):
    """The check itself: a from-import (absolute, relative, lazy), an attribute of an imported module, of a module
    reached through its package, and of a test helper module; a module's own private names and a class's are not
    another module's."""
    pkg = tmp_path / "pipeline"
    pkg.mkdir()
    (tmp_path / "tests").mkdir()
    (pkg / "a.py").write_text(
        "from . import b\nfrom .b import _x\nimport slamobs.pipeline.b as bb\nfrom slamobs.pipeline import b as c\n"
        "import slamobs\nimport helper\n_own = 1\n\n"
        "def f():\n    from slamobs.pipeline.b import _lazy\n"
        "    return b._y, bb._z, c._w, slamobs.pipeline.b._v, helper._h, _own, b.Public._method\n"
    )
    (pkg / "b.py").write_text("")
    (tmp_path / "tests" / "helper.py").write_text("")
    monkeypatch.setattr(__import__(__name__), "ROOT", tmp_path)
    modules = {"slamobs", "slamobs.pipeline", "slamobs.pipeline.a", "slamobs.pipeline.b", "helper"}
    got = sorted(line.split(": ", 1)[1] for line in uses_of_private_names(pkg / "a.py", modules))
    want = ["slamobs.pipeline.b." + n for n in ("_lazy", "_v", "_w", "_x", "_y", "_z")] + ["helper._h"]
    assert got == sorted(want)


def test_no_module_uses_another_modules_private_names():
    files = project_files()
    modules = {module_name(p) for p in files} | {PACKAGE}
    found = [use for path in files for use in uses_of_private_names(path, modules)]
    assert not found, "private names used from another module (make them public, or test through the caller):\n" + (
        "\n".join(found)
    )
