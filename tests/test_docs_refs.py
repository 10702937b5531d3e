"""The documentation matches the tree: every section reference points at a section of docs/observers.md that
exists, section numbers there are unique, nothing cites a document outside the repository, and the module map
of docs/development.md lists exactly the modules there are."""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OBSERVERS_MD = ROOT / "docs" / "observers.md"
SKIP_DIRS = {".venv", ".venv-evo", ".git", "demo_out", "__pycache__", "build", "dist"}
HEADING = re.compile(r"^#{2,4} (\d+(?:\.\d+)*)\.? ", re.M)
REF = re.compile("\N{SECTION SIGN}+\\s*(\\d+(?:\\.\\d+)*)")
#: Where section numbers could be meant for another document than docs/observers.md.
FOREIGN = re.compile(r"spec/observers\.md|\bspec \N{SECTION SIGN}|\.\./shared/spec|\.\./seeds|seed[ -]\d{3}", re.I)
#: Tests that keep such words out of user-facing text name them on purpose.
GUARDS = {"tests/test_cli_consistency.py", "tests/test_docs_refs.py"}


def _files(*suffixes: str) -> list[Path]:
    return sorted(
        p
        for p in ROOT.rglob("*")
        if p.suffix in suffixes and p.is_file() and not SKIP_DIRS.intersection(p.relative_to(ROOT).parts)
    )


def _sections() -> list[str]:
    return HEADING.findall(OBSERVERS_MD.read_text(encoding="utf-8"))


def test_section_numbers_of_observers_md_are_unique():
    twice = [n for n, c in Counter(_sections()).items() if c > 1]
    assert not twice, f"docs/observers.md numbers these sections more than once: {twice}"


def test_every_section_reference_exists_in_observers_md():
    """Every ``§N`` in the repository's .py/.md files names a section of docs/observers.md (the only numbered
    document); outside that file, the file says which document it means before its first reference."""
    sections = set(_sections())
    missing, unanchored = [], []
    for path in _files(".py", ".md", ".json"):
        text = path.read_text(encoding="utf-8", errors="replace")
        rel = path.relative_to(ROOT).as_posix()
        for m in REF.finditer(text):
            line = text.count("\n", 0, m.start()) + 1
            if m.group(1) not in sections:
                missing.append(f"{rel}:{line}: \N{SECTION SIGN}{m.group(1)}")
            if path != OBSERVERS_MD and "observers.md" not in text[: m.start()]:
                unanchored.append(f"{rel}:{line}")
    assert not missing, "references to sections docs/observers.md does not have:\n" + "\n".join(missing)
    assert not unanchored, "section references without docs/observers.md named before them:\n" + "\n".join(unanchored)


def test_no_references_to_documents_outside_the_repository():
    found = []
    for path in _files(".py", ".md", ".json"):
        if path.relative_to(ROOT).as_posix() in GUARDS:
            continue
        for i, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
            if FOREIGN.search(line):
                found.append(f"{path.relative_to(ROOT).as_posix()}:{i}: {line.strip()}")
    assert not found, "references to documents outside the repository:\n" + "\n".join(found)


def test_module_map_lists_exactly_the_modules():
    """The module map (docs/development.md) names every module of the package once, and no module that does not
    exist."""
    text = (ROOT / "docs" / "development.md").read_text(encoding="utf-8")
    start = text.index("## Module map")
    end = text.find("\n#", start + 1)
    rows = re.findall(r"^\| `([^`]+\.py)` \|", text[start : end if end > 0 else None], re.M)
    twice = [r for r, c in Counter(rows).items() if c > 1]
    tree = {
        p.relative_to(ROOT).as_posix()
        for p in _files(".py")
        if p.relative_to(ROOT).parts[0] in ("pipeline", "cli", "schemas") or p == ROOT / "__init__.py"
    }
    assert not twice, f"listed more than once: {twice}"
    assert not tree - set(rows), f"missing from the module map (docs/development.md): {sorted(tree - set(rows))}"
    assert not set(rows) - tree, f"in the module map (docs/development.md), not the tree: {sorted(set(rows) - tree)}"


#: A repository path named in prose: a top-level folder of the repository, then a file or folder name.
PATH_REF = re.compile(r"(?<![\w./-])((?:pipeline|cli|schemas|tests|benchmarks|docs|sample_logs|\.ci)/[\w./-]*\w)")


def test_named_files_exist():
    """Files the code, the docs and pyproject.toml name exist (tests are left out: they name files they make)."""
    missing = []
    for path in _files(".py", ".md", ".toml"):
        rel = path.relative_to(ROOT)
        if rel.parts[0] == "tests":
            continue
        for i, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
            for m in PATH_REF.finditer(line):
                ref = m.group(1)
                if re.search(r"[A-Z]{4}|_x\.|_$|\*|\{", ref):  # placeholders: benchmarks/NAME.py, tests/test_x.py
                    continue
                if not any(p.exists() for p in (ROOT / ref, path.parent / ref, ROOT / "pipeline" / ref)):
                    missing.append(f"{rel.as_posix()}:{i}: {ref}")
    assert not missing, "files named that do not exist:\n" + "\n".join(missing)


YAML_BLOCK = re.compile(r"^```ya?ml\n(.*?)^```", re.M | re.S)


def test_config_examples_in_the_docs_are_valid_configs():
    """Every YAML config shown in the README and docs/ (a mapping with config keys) passes the config schema, so
    a user who copies one, e.g. the full key list of docs/reading-logs.md, gets a run and not an error."""
    import yaml

    from slamobs.pipeline.errors import InputError
    from slamobs.pipeline.config import parse_config

    bad = []
    for path in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        text = path.read_text(encoding="utf-8")
        for m in YAML_BLOCK.finditer(text):
            data = yaml.safe_load(m.group(1))
            if not isinstance(data, dict):
                continue
            where = f"{path.relative_to(ROOT).as_posix()}:{text.count(chr(10), 0, m.start()) + 1}"
            try:
                parse_config(data, where)
            except InputError as err:  # its message names the block: file and line
                bad.append(str(err))
    assert not bad, "config examples the schema rejects:\n" + "\n".join(bad)
