"""No function under services/ longer than 80 lines: a behaviour a newcomer can read in one
screen or two."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LIMIT = 80


def long_functions(root: Path) -> dict[tuple[str, str], int]:
    out = {}
    for path in sorted(root.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = node.end_lineno - node.lineno + 1
                if lines > LIMIT:
                    out[(str(path.relative_to(ROOT)), node.name)] = lines
    return out


def test_no_function_is_longer_than_80_lines():
    found = long_functions(ROOT / "services")
    assert not found, "split these (file, function): lines\n" + "\n".join(
        f"{f} {name}: {n}" for (f, name), n in sorted(found.items())
    )
