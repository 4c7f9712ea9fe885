"""No module of the library (stack/, twin/, vigil/) or of bench/ imports another
module's private names (issue 24): what one module needs of another is public."""

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _private_imports(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    where = path.relative_to(REPO)
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module != "__future__":
            modules = (node.module or "").split(".")
            for alias in node.names:
                if alias.name.startswith("_") and not alias.name.startswith("__"):
                    out.append(f"{where}:{node.lineno}: {node.module}.{alias.name}")
            if any(m.startswith("_") and not m.startswith("__") for m in modules):
                out.append(f"{where}:{node.lineno}: {node.module}")
        elif isinstance(node, ast.Import):
            for alias in node.names:
                parts = alias.name.split(".")
                if any(p.startswith("_") and not p.startswith("__") for p in parts):
                    out.append(f"{where}:{node.lineno}: {alias.name}")
    return out


def test_no_module_imports_another_modules_private_names():
    files = [p for d in ("stack", "twin", "vigil", "bench") for p in (REPO / d).rglob("*.py")]
    assert len(files) > 50
    found = [line for p in files for line in _private_imports(p)]
    assert found == [], "\n".join(found)
