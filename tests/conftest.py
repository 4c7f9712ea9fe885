"""Shared test set-up.

ROS 2 tests talk real DDS. Each pytest process gets its own domain id and stays on
localhost so that concurrent test runs (and any robot on the network) never hear
each other. MuJoCo renders headless through EGL.
"""

import os

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
if "ROS_DOMAIN_ID" not in os.environ:
    # a domain no other vigil run or test session on this machine holds (released at exit)
    from vigil.ros_domain import claim_domain

    _DOMAIN = claim_domain()
    os.environ["ROS_DOMAIN_ID"] = str(_DOMAIN.domain_id)
os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")


import pytest  # noqa: E402


@pytest.fixture
def ros():
    """rclpy initialised for one test, and an executor to spin its nodes."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    rclpy.init()
    executor = SingleThreadedExecutor()
    yield executor
    executor.shutdown()
    rclpy.shutdown()


@pytest.fixture(scope="module")
def private_ros_domain():
    """A ROS domain of the module's own (vigil.ros_domain), for tests where messages of
    other test sessions on the shared per-process domain were seen to leak in; use with
    ``pytestmark = pytest.mark.usefixtures("private_ros_domain")``."""
    from vigil.ros_domain import claim_domain

    claim = claim_domain()
    old = os.environ.get("ROS_DOMAIN_ID")
    os.environ["ROS_DOMAIN_ID"] = str(claim.domain_id)
    yield claim.domain_id
    if old is None:
        os.environ.pop("ROS_DOMAIN_ID", None)
    else:
        os.environ["ROS_DOMAIN_ID"] = old
    claim.release()


# Files whose tests run the twin end to end, render through EGL or run HOG on rendered
# frames: `pytest -m "not slow"` leaves them out (the quick loop), CI runs everything.
SLOW_FILES = {
    "test_system_twin.py",
    "test_twin_hog.py",
    "test_perception_twin.py",
    "test_nav_twin.py",
    "test_twin_snapshot.py",
    "test_twin_determinism.py",
    "test_twin_bridge.py",
}


def pytest_collection_modifyitems(config, items):
    """Mark every test that uses the ``ros`` fixture ``ros``, and those above ``slow``."""
    for item in items:
        if "ros" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.ros)
        if item.path.name in SLOW_FILES:
            item.add_marker(pytest.mark.slow)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """A failed test that ran the stack shows its nodes' warnings and errors (the
    twin bridge's lock-step lines among them): CI keeps no run folder to look into."""
    outcome = yield
    report = outcome.get_result()
    tmp = getattr(item, "funcargs", {}).get("tmp_path")
    if report.when != "call" or not report.failed or tmp is None:
        return
    lines = []
    for log in sorted(tmp.rglob("logs/*.log"))[:40]:
        try:
            text = log.read_text(errors="replace").splitlines()
        except OSError:
            continue
        worth = [x for x in text if "[WARN]" in x or "[ERROR]" in x or "Traceback" in x]
        if worth:
            lines.append(f"--- {log.relative_to(tmp)} ({len(worth)} of {len(text)} lines)")
            lines.extend(worth if len(worth) <= 30 else worth[:15] + ["..."] + worth[-15:])
    if lines:
        report.sections.append(("run logs: warnings and errors", "\n".join(lines)))
