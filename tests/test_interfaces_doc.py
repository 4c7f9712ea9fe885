"""docs/INTERFACES.md lists every topic of stack/topics.py, and the interface packages
define what the doc says they do."""

from __future__ import annotations

from pathlib import Path

import stack.topics as topics

ROOT = Path(__file__).resolve().parents[1]


def test_every_topic_is_documented():
    doc = (ROOT / "docs" / "INTERFACES.md").read_text()
    names = {v for k, v in vars(topics).items() if k.isupper() and isinstance(v, str)}
    missing = sorted(n for n in names if f"`{n}`" not in doc)
    assert not missing, f"topics missing from docs/INTERFACES.md: {missing}"


def test_tf_message_is_upstreams_definition():
    text = (ROOT / "interfaces" / "tf2_msgs" / "msg" / "TFMessage.msg").read_text()
    assert text.strip() == "geometry_msgs/TransformStamped[] transforms"


def test_every_interface_file_is_built_and_documented():
    pkg = ROOT / "interfaces" / "vigil_interfaces"
    cmake = (pkg / "CMakeLists.txt").read_text()
    doc = (ROOT / "docs" / "INTERFACES.md").read_text()
    files = sorted(pkg.glob("msg/*.msg")) + sorted(pkg.glob("action/*.action"))
    assert files
    for f in files:
        rel = f.relative_to(pkg).as_posix()
        assert f'"{rel}"' in cmake, f"{rel} is not in vigil_interfaces/CMakeLists.txt"
        assert f"`{f.stem}`" in doc or f"/{f.stem}`" in doc, f"{f.stem} is not in the doc"
