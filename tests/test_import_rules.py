"""Who may import whom, read from the source with ``ast`` (nothing is imported):

- a service module imports from ``followbot.schemas`` and ``followbot.services`` only, never
  from the command-line package (``followbot.<anything else>``);
- a stage (laser_legs, vision_verify, tracker, controller, sim, camera_blobs...) never imports
  another stage: what two stages share lives in ``services/common`` or ``services/runtime``;
- nothing under services/ imports the simulator except the simulator itself.

Research tooling that needs several stages and the simulator lives in ``followbot/research``."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SERVICES = ROOT / "services"
SHARED = {"runtime", "common"}


def _imports(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module) of every import in ``path``, lazy ones included."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = ["followbot", *path.relative_to(ROOT).parent.parts]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            out.append((node.lineno, module))
    return out


def _stage(path: Path, root: Path) -> str | None:
    parts = path.relative_to(root).parts
    return parts[0] if len(parts) > 1 else None


def violations(root: Path = SERVICES) -> list[str]:
    found = []
    for path in sorted(root.rglob("*.py")):
        own = _stage(path, root)
        for line, module in _imports(path):
            seg = module.split(".")
            if seg[0] != "followbot":
                continue
            where = f"{path.relative_to(ROOT)}:{line} imports {module}"
            if len(seg) < 2 or seg[1] not in ("schemas", "services"):
                found.append(f"{where}: a service imports the command-line package")
                continue
            if seg[1] != "services" or len(seg) < 3:
                continue
            other = seg[2]
            if other == "sim" and own != "sim":
                found.append(f"{where}: only the simulator imports the simulator")
            elif other not in SHARED and own not in SHARED and own and other != own:
                found.append(f"{where}: a stage imports another stage")
    return found


def test_services_follow_the_import_rules():
    found = violations()
    assert not found, "\n".join(found)


def test_the_rules_catch_each_kind_of_violation(tmp_path, monkeypatch):
    services = tmp_path / "services"
    for stage in ("tracker", "sim", "common"):
        (services / stage).mkdir(parents=True)
    (services / "tracker" / "bad.py").write_text(
        "from followbot.geometry import x\n"
        "from ..sim import scenario\n"
        "def f():\n    from followbot.services.controller.core import y\n"
        "from followbot.services.common.scan import ok\n"
    )
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    found = violations(services)
    assert len(found) == 3, found
    assert "command-line package" in found[0]
    assert "only the simulator" in found[1]
    assert "another stage" in found[2] and ":4 " in found[2]
