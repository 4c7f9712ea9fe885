"""The architecture's rules, checked on the source (README, "Architecture").

- no import cycle between the project's modules;
- imports go one way: ``vigil`` (application) -> ``twin`` -> ``stack``; ``stack`` never
  imports ``twin`` or ``vigil``, ``twin`` never imports ``vigil``;
- algorithm modules never import rclpy: in ``stack`` and ``twin`` only ``node_*.py``,
  ``ros_*.py`` and the twin's bridge talk ROS (``vigil``, the application, may);
- algorithm modules import no message package either (``*_msgs``, ``*_interfaces``):
  typed messages are converted in ``stack/ros_msgs.py`` (issue 14) and the nodes;
- a module over 500 lines says why in its docstring;
- the planning library (``stack/planning``, issue 24) has no module over 500 lines, and
  none of its modules imports a private name (``_x``) of another project module or
  reads one of another object (``search._closure()``);
- ROS topic names are written only in ``stack/topics.py``: anywhere else a string literal
  that looks like a topic name (``"/nav/result"``) fails.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("stack", "twin", "vigil")
LAYER = {"stack": 0, "twin": 1, "vigil": 2}


def modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in (REPO / pkg).rglob("*.py"):
            rel = path.relative_to(REPO).with_suffix("")
            parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
            out[".".join(parts)] = path
    return out


def imports_of(path: Path, name: str, known: dict[str, Path]) -> set[str]:
    """The project modules ``name`` imports (at module level or inside functions)."""
    tree = ast.parse(path.read_text())
    found = set()
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(tree):
        targets = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*up, base] if base else up)
            targets = [base] + [f"{base}.{a.name}" for a in node.names]
        for t in targets:
            while t and t not in known:
                t = t.rpartition(".")[0]
            if t and t != name:
                found.add(t)
    return found


def test_no_import_cycle():
    known = modules()
    graph = {m: imports_of(p, m, known) for m, p in known.items()}
    # packages' __init__ modules are passed through on the way to their submodules
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> None:
        state[m] = 1
        stack.append(m)
        for n in sorted(graph.get(m, ())):
            if state.get(n) == 1:
                cycle = stack[stack.index(n) :] + [n]
                raise AssertionError("import cycle: " + " -> ".join(cycle))
            if n not in state:
                visit(n)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)


def test_imports_go_one_way():
    known = modules()
    bad = []
    for m, path in known.items():
        for n in imports_of(path, m, known):
            if LAYER[n.split(".")[0]] > LAYER[m.split(".")[0]]:
                bad.append(f"{m} imports {n}")
    assert not bad, "imports against the layers: " + "; ".join(sorted(bad))


def test_only_nodes_import_rclpy():
    bad = []
    for m, path in modules().items():
        stem = path.stem
        if stem.startswith(("node_", "ros_")) or m == "twin.bridge_node" or m.startswith("vigil."):
            continue
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [node.module or ""]
            if any(n == "rclpy" or n.startswith("rclpy.") for n in names):
                bad.append(m)
    assert not bad, f"algorithm modules importing rclpy: {sorted(set(bad))}"


def test_only_nodes_and_the_codec_import_message_packages():
    """Issue 14: domain types <-> messages only in stack/ros_msgs.py and node files."""
    bad = []
    for m, path in modules().items():
        stem = path.stem
        if stem.startswith(("node_", "ros_")) or m == "twin.bridge_node" or m.startswith("vigil."):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and not node.level:
                names = [node.module or ""]
            top = {n.split(".")[0] for n in names}
            if any(t.endswith(("_msgs", "_interfaces")) for t in top):
                bad.append(m)
    assert not bad, f"algorithm modules importing message packages: {sorted(set(bad))}"


def test_long_modules_say_why():
    bad = []
    for m, path in modules().items():
        text = path.read_text()
        if text.count("\n") <= 500:
            continue
        doc = ast.get_docstring(ast.parse(text)) or ""
        if "500 lines" not in doc:
            bad.append(f"{m} ({text.count(chr(10))} lines)")
    assert not bad, "modules over 500 lines without a docstring sentence saying why: " + ", ".join(
        bad
    )


PLANNING = REPO / "stack" / "planning"


def private_imports(path: Path, name: str, known: dict[str, Path]) -> list[str]:
    """The private names (``_x``, not dunders) module ``name`` takes from other project
    modules: ``from m import _x``, ``import m._x``, and ``m._x`` read through a module
    it imported (``from stack.planning import clock`` then ``clock._y``)."""
    tree = ast.parse(path.read_text())
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]

    def private(n: str) -> bool:
        return n.startswith("_") and not (n.startswith("__") and n.endswith("__"))

    found = []
    aliases: set[str] = set()  # local names bound to project modules
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                parts = a.name.split(".")
                if any(private(p) for p in parts) and parts[0] in PACKAGES:
                    found.append(f"{name}:{node.lineno} import {a.name}")
                if a.name in known:
                    aliases.add(a.asname or parts[0])
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*up, base] if base else up)
            if base.split(".")[0] not in PACKAGES or base == name:
                continue
            for a in node.names:
                if private(a.name) or any(private(p) for p in base.split(".")):
                    found.append(f"{name}:{node.lineno} from {base} import {a.name}")
                elif f"{base}.{a.name}" in known:
                    aliases.add(a.asname or a.name)
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Attribute)
            and isinstance(node.value, ast.Name)
            and node.value.id in aliases
            and private(node.attr)
        ):
            found.append(f"{name}:{node.lineno} {node.value.id}.{node.attr}")
    return found


def test_private_import_check_finds_them(tmp_path):
    """The check itself, on a probe module in a project package."""
    known = modules()
    src = tmp_path / "probe.py"
    src.write_text(
        "from stack.planning import clock\n"
        "from stack.planning.sarsop import BeliefTreeSearch\n"
        "from stack.planning.policy import _attr\n"
        "import numpy as np\n"
        "x = clock._private + np._NoValue.__class__ + clock.__name__\n"
    )
    got = private_imports(src, "stack.planning.probe", known)
    assert got == [
        "stack.planning.probe:3 from stack.planning.policy import _attr",
        "stack.planning.probe:5 clock._private",
    ]
    src.write_text("def f(search):\n    return search._closure() + super()._done() + self._x\n")
    assert private_reads(src) == ["2 search._closure"]


def test_planning_modules_import_no_private_names():
    """Issue 24: what one module of the planning library needs from another has a
    public name (a newcomer can tell the library's interfaces from its details)."""
    known = modules()
    bad = []
    for m, path in sorted(known.items()):
        if path.is_relative_to(PLANNING):
            bad.extend(private_imports(path, m, known))
    assert not bad, "private names imported across modules: " + "; ".join(bad)


def private_reads(path: Path) -> list[str]:
    """``x._y`` in ``path`` with x not ``self``, ``cls`` or ``super()``: another
    object's private attribute or method (``search._closure()`` from another module)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if not isinstance(node, ast.Attribute) or not node.attr.startswith("_"):
            continue
        if node.attr.startswith("__") and node.attr.endswith("__"):
            continue
        v = node.value
        if isinstance(v, ast.Name) and v.id in ("self", "cls"):
            continue
        if isinstance(v, ast.Call) and isinstance(v.func, ast.Name) and v.func.id == "super":
            continue
        found.append(f"{node.lineno} {ast.unparse(node)}")
    return found


def test_planning_modules_read_no_private_attributes_of_other_objects():
    """Issue 24: a module of the planning library uses another object through its
    public names (``search.write_seconds_per_value()``, ``pomdp.noted(key)``), not its
    private ones; its own object's (``self._x``) are its own business."""
    bad = [
        f"{path.relative_to(REPO)}:{hit}"
        for path in sorted(PLANNING.rglob("*.py"))
        for hit in private_reads(path)
    ]
    assert not bad, "private attributes of other objects read: " + "; ".join(bad)


def test_planning_modules_under_500_lines():
    """Issue 24: every module of the planning library fits in 500 lines."""
    bad = []
    for path in sorted(PLANNING.rglob("*.py")):
        n = path.read_text().count("\n")
        if n > 500:
            bad.append(f"{path.relative_to(REPO)} ({n} lines)")
    assert not bad, "stack/planning modules over 500 lines: " + ", ".join(bad)


TOPIC_LIKE = re.compile(r"(/[a-z][a-z0-9_]*)+")  # an absolute ROS name, as a whole string
NOT_TOPICS = ("/proc/", "/tmp/", "/opt/", "/usr/", "/dev/", "/etc/")  # file-system paths
# literals that are ROS names but not topics: the SROS2 enclave root
NOT_TOPIC_NAMES = {("vigil/security.py", "/vigil")}


def topic_literals(path: Path) -> list[tuple[int, str]]:
    """String literals in ``path`` (docstrings aside) that look like topic names."""
    tree = ast.parse(path.read_text())
    docs = {
        id(n.body[0].value)
        for n in ast.walk(tree)
        if isinstance(n, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef)
        and n.body
        and isinstance(n.body[0], ast.Expr)
    }
    return [
        (n.lineno, n.value)
        for n in ast.walk(tree)
        if isinstance(n, ast.Constant)
        and isinstance(n.value, str)
        and id(n) not in docs
        and TOPIC_LIKE.fullmatch(n.value)
        and not n.value.startswith(NOT_TOPICS)
    ]


def test_topic_literals_flagged(tmp_path):
    """The check itself: it finds a literal topic and passes over paths and docstrings."""
    src = tmp_path / "probe.py"
    src.write_text(
        '"""Publishes ``/nav/result``."""\n'
        'X = "/nav/result"\nY = "/proc/self/stat"\nZ = f"/vigil/{X}"\n'
    )
    assert topic_literals(src) == [(2, "/nav/result")]


def test_topic_names_only_in_topics_module():
    bad = []
    for folder in (*PACKAGES, "scripts", "bench"):
        for path in sorted((REPO / folder).rglob("*.py")):
            rel = path.relative_to(REPO).as_posix()
            if rel == "stack/topics.py":
                continue
            for line, name in topic_literals(path):
                if (rel, name) not in NOT_TOPIC_NAMES:
                    bad.append(f"{rel}:{line} {name!r}")
    assert not bad, "topic names outside stack/topics.py (add a constant there): " + ", ".join(bad)
