"""The report's modules stay readable (issue 24): no function over 80 lines in the evaluation package or the
results MCAP writer (``evaluate_tables`` was 113 lines, ``results_mcap._write`` 128), and each report section is
one class with ``process_data`` and ``get_statistic``."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_LINES = 80
FILES = sorted((ROOT / "pipeline" / "evaluation").glob("*.py")) + [ROOT / "pipeline" / "results_mcap.py"]


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_no_function_over_80_lines(path):
    tree = ast.parse(path.read_text(encoding="utf-8"))
    long = {node.name: node.end_lineno - node.lineno + 1 for node in ast.walk(tree)
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
            and node.end_lineno - node.lineno + 1 > MAX_LINES}
    assert not long, f"{path.name}: functions over {MAX_LINES} lines (split them into named steps): {long}"


def test_each_report_section_is_one_class():
    from slamobs.pipeline.evaluation import sections

    classes = [c for c in vars(sections).values()
               if isinstance(c, type) and issubclass(c, sections.Section) and c is not sections.Section]
    assert len(classes) == 8
    for cls in classes:
        assert callable(getattr(cls, "process_data", None)) and callable(cls.get_statistic), cls.__name__
