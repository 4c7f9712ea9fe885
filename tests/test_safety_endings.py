"""Every ending of ``vigil run`` and ``vigil launch`` writes ``run.json`` with its first
cause in one line and exits with the code of that cause (issue 23; docs/SAFETY.md,
"Endings").

The ``vigil run`` cases use the thesis table's observations (planner + table player: two
light processes, no twin) and a policy of zeros; the ``vigil launch`` cases stand in
small processes for the nodes. The full-disk case of ``vigil run`` mounts a tmpfs (root
only); the node's and the bag's own full-disk handling is shown on ``/dev/full`` and on a
file system filled by the test.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from stack.exits import TEARDOWN_SIGNAL
from vigil import ending as E

REPO = Path(__file__).resolve().parents[1]
SCENARIO = REPO / "scenarios" / "5.1.1.yaml"


def _deployment(tmp_path: Path, planner: dict | None = None, **nodes) -> Path:
    """A twin deployment with a zero policy for the 5.1.1 task (no solving); ``planner``
    overrides planner parameters."""
    from stack.planning.model import build_model
    from stack.planning.policy import AlphaPolicy
    from stack.planning.task import load_task
    from vigil.scenario import load_scenario

    task = load_scenario(SCENARIO).task
    n = build_model(load_task(task)).flat().n_states
    AlphaPolicy(np.zeros((2, n)), np.array([0, 1]), {}).save(tmp_path / "p.npz")
    config = yaml.safe_load((REPO / "config" / "twin.yaml").read_text())
    config.update(task=str(task), policy=str(tmp_path / "p.npz"))
    config["twin"]["scene"] = str(REPO / "config" / "twin-scene.yaml")
    config["nodes"].update(nodes)
    config["planner"].update(planner or {})
    path = tmp_path / "dep.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


LONG_STEPS = 2000  # the table's last row repeats: a run an idle machine cannot finish


def _long_scenario(tmp_path: Path) -> Path:
    """5.1.1 with LONG_STEPS steps: a signal or a kill sent after step 1 always comes
    before the end (12 table steps took less than the signal's delivery when idle)."""
    data = yaml.safe_load(SCENARIO.read_text())
    data.update(steps=LONG_STEPS, task=str((SCENARIO.parent / data["task"]).resolve()))
    path = tmp_path / "long.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _start_run(
    tmp_path: Path, out: Path, config: Path, *extra: str, scenario: Path = SCENARIO
) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    env.pop("ROS_DOMAIN_ID", None)  # the run claims its own
    return subprocess.Popen(
        [sys.executable, "-m", "vigil.cli", "run", str(scenario), "--config", str(config),
         "--observations", "table", "--out", str(out), *extra],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )  # fmt: skip


def _wait_steps(out: Path, n: int, proc: subprocess.Popen, wall_s: float = 240.0) -> None:
    deadline = time.monotonic() + wall_s
    steps = out / "steps.jsonl"
    while time.monotonic() < deadline:
        if steps.exists() and len(steps.read_text().splitlines()) >= n:
            return
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.2)
    raise AssertionError(f"no {n} steps in {wall_s} s")


def _run_json(out: Path) -> dict:
    return json.loads((out / "run.json").read_text())


def _assert_left_cleanly(record: dict, names: tuple[str, ...]) -> None:
    """Each node exited 0 on the launcher's SIGINT, or its work was done and only its
    Fast DDS teardown hung (eProsima/Fast-DDS#6502, seen in CI under load): then its own
    alarm ended it, and run.json carries the launcher's warning naming it, no failure."""
    assert set(record["exit_codes"]) == set(names)
    for name in names:
        code = record["exit_codes"][name]
        if code == -TEARDOWN_SIGNAL:
            assert any(w.startswith(f"{name}: its ROS teardown hung") for w in record["warnings"])
        else:
            assert code == 0, (name, code)
    assert record["failures"] == []


@pytest.mark.parametrize(
    ("sig", "code"), [(signal.SIGTERM, E.EXIT_SIGTERM), (signal.SIGINT, E.EXIT_SIGINT)]
)
def test_a_signal_to_vigil_run_mid_run_writes_run_json_and_exits_with_its_code(tmp_path, sig, code):
    """SIGTERM (or Ctrl-C) after the first step: the nodes stop cleanly, the report of
    the steps made is written, run.json names the signal, exit 143 (130). Before, SIGTERM
    killed vigil on the spot (no run.json, no report) and Ctrl-C ended in a traceback."""
    out = tmp_path / "run"
    proc = _start_run(tmp_path, out, _deployment(tmp_path), scenario=_long_scenario(tmp_path))
    try:
        _wait_steps(out, 1, proc)
        proc.send_signal(sig)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    name = signal.Signals(sig).name
    assert proc.returncode == code, (stdout, stderr)
    record = _run_json(out)
    assert record["ending"] == name and record["exit_code"] == code
    assert re.fullmatch(rf"{name}: stopped at step \d+/{LONG_STEPS}", record["cause"])
    _assert_left_cleanly(record, ("planner", "table_player"))
    assert record["report"] == "written" and (out / "steps.md").read_text().strip()
    assert stderr.strip().splitlines()[-1] == f"vigil run: {record['cause']}"
    assert "Traceback" not in stderr


def test_a_killed_node_is_named_in_run_json_and_exit_code_3(tmp_path):
    """A node SIGKILLed from outside (no restart left): the cause names it and the signal."""
    out = tmp_path / "run"
    proc = _start_run(tmp_path, out, _deployment(tmp_path, max_restarts=0),
                      scenario=_long_scenario(tmp_path))  # fmt: skip
    try:
        _wait_steps(out, 1, proc)
        log = ""
        while "table_player (pid" not in log:  # the launcher's line gives its pid
            log += proc.stdout.readline()
        pid = int(re.search(r"table_player \(pid (\d+)\)", log).group(1))
        os.kill(pid, signal.SIGKILL)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == E.EXIT_NODE, stderr
    record = _run_json(out)
    assert record["ending"] == "node"
    assert record["cause"].startswith("table_player exited (code -9, SIGKILL)")
    assert stderr.strip().splitlines()[-1] == f"vigil run: {record['cause']}"


def test_a_run_past_its_timeout_writes_run_json_and_exits_5(tmp_path):
    """The planner's first decision waits 60 s, so the 1 s timeout comes first whatever
    the machine's speed (an idle machine ran all 12 table steps within 1 s)."""
    out = tmp_path / "run"
    dep = _deployment(tmp_path, planner={"start_delay_s": 60.0})
    proc = _start_run(tmp_path, out, dep, "--timeout", "1")
    stdout, stderr = proc.communicate(timeout=180)
    assert proc.returncode == E.EXIT_TIMEOUT, stderr
    record = _run_json(out)
    assert record["ending"] == "timeout" and record["cause"].startswith("timed out after 1 s")


def _mount_tmpfs(path: Path, size: str) -> bool:
    path.mkdir()
    if os.geteuid() != 0:
        return False
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                          capture_output=True)  # fmt: skip
    return done.returncode == 0


def _fill(folder: Path) -> None:
    """Fill the file system of ``folder`` to the last byte."""
    with open(folder / "filler", "wb") as f:
        try:
            while True:
                f.write(b"\0" * 4096)
                f.flush()
        except OSError:
            pass
        try:
            f.close()
        except OSError:
            pass


def test_a_full_disk_mid_run_names_the_disk_and_still_writes_run_json(tmp_path):
    """The run folder's disk fills up after the first step (a tmpfs, filled by the test):
    the planner cannot append its step, exits with the disk-full code and is not
    restarted; vigil frees its reserve and writes run.json naming the disk, exit 6.
    Before: the planner died with a traceback, was restarted into the same full disk and
    run.json was never written."""
    disk = tmp_path / "disk"
    if not _mount_tmpfs(disk, "16m"):
        pytest.skip("needs root and mount -t tmpfs")
    try:
        out = disk / "run"
        proc = _start_run(tmp_path, out, _deployment(tmp_path))
        try:
            _wait_steps(out, 1, proc)
            _fill(disk)
            steps_when_full = len((out / "steps.jsonl").read_text().splitlines())
            stdout, stderr = proc.communicate(timeout=180)
        finally:
            if proc.poll() is None:
                proc.kill()
        if steps_when_full >= 12:  # the table run is fast: it can end before the disk fills
            pytest.skip(f"the run outpaced the filling disk ({steps_when_full} steps)")
        assert proc.returncode == E.EXIT_DISK_FULL, (stdout, stderr)
        record = _run_json(out)
        assert record["ending"] == "disk full"
        assert record["cause"].startswith("disk full: planner exited (code 4")
        assert "Traceback" not in stderr
        assert stderr.strip().splitlines()[-1] == f"vigil run: {record['cause']}"
    finally:
        subprocess.run(["umount", "-l", str(disk)], check=False)


def test_a_node_that_finds_its_disk_full_exits_4_with_one_line(tmp_path):
    """stack.ros_main.spin_node: ENOSPC in a callback (here a timer writing to
    /dev/full) ends the node with EXIT_DISK_FULL and one [FATAL] line, no traceback."""
    code = textwrap.dedent(
        """
        from rclpy.node import Node
        from stack.ros_main import spin_node

        class Writer(Node):
            def __init__(self):
                super().__init__("writer")
                self.f = open("/dev/full", "w")
                self.create_timer(0.05, self.tick)

            def tick(self):
                self.f.write("x" * 10000)
                self.f.flush()

        spin_node(Writer)
        """
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, env=dict(os.environ, PYTHONPATH=str(REPO)))  # fmt: skip
    assert done.returncode == 4, done.stderr
    assert "Traceback" not in done.stderr
    assert "[FATAL] Writer: disk full: [Errno 28] No space left on device" in done.stderr


def test_a_bag_whose_disk_fills_up_is_closed_with_its_index(tmp_path):
    """The bag writer holds a reserve: once the disk is full, close() frees it and the
    bag gets its summary and metadata.yaml; it reads back up to where the disk filled."""
    from rosbags.rosbag2 import Reader

    from vigil.bag import BagWriter

    disk = tmp_path / "disk"
    if not _mount_tmpfs(disk, "8m"):
        pytest.skip("needs root and mount -t tmpfs")
    try:
        bag = BagWriter(disk / "bag", reserve_bytes=1 << 20)
        bag.add_topic("/scan_count", "std_msgs/msg/UInt32")
        written = 0
        with pytest.raises(OSError, match="No space left"):
            rng = np.random.default_rng(0)
            for i in range(10**6):  # incompressible payloads fill the disk
                bag.write("/scan_count", i, b"\0\1\0\0" + rng.bytes(4))
                written += 1
                if i % 1000 == 0:
                    (disk / f"pad{i}").write_bytes(rng.bytes(200_000))
        bag.close()
        with Reader(disk / "bag") as reader:
            n = sum(1 for _ in reader.messages())
        assert n > 0 and n <= written
    finally:
        subprocess.run(["umount", "-l", str(disk)], check=False)


# -- vigil launch ----------------------------------------------------------------------
LAUNCH = textwrap.dedent(
    """
    import sys
    from pathlib import Path
    from types import SimpleNamespace

    import vigil.launch_command as L
    from vigil.processes import ProcessSpec
    from vigil.system import System

    out = Path(sys.argv[1])
    nodes = {"sleeper": sys.argv[3], "other": sys.argv[2]}
    specs = [ProcessSpec(n, "", restart=False, command=[sys.executable, "-u", "-c", c])
             for n, c in nodes.items()]
    nodes = SimpleNamespace(max_restarts=3, stop_timeout_s=5.0, restart_delay_s=0.0)
    dep = SimpleNamespace(mode="hardware", ros=SimpleNamespace(domain_id=-1), nodes=nodes)

    def prepare(*args, **kwargs):
        out.mkdir()
        return dep, System(out, specs, {}, {}), "id"

    class Watch:
        def __init__(self, *a): pass
        def poll(self): return []
        def close(self): pass

    L.prepare_launch, L.GraphWatch = prepare, Watch
    sys.exit(L.launch("unused", out))
    """
)
SLEEP = (
    "import time\ntry:\n    print('ready', flush=True)\n    time.sleep(600)\n"
    "except KeyboardInterrupt:\n    pass\n"
)


def _launch(tmp_path: Path, other: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-c", LAUNCH, str(tmp_path / "launch"), other, SLEEP],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env=dict(os.environ, PYTHONPATH=str(REPO)),
    )  # fmt: skip


def _wait_ready(tmp_path: Path) -> None:
    logs = [tmp_path / "launch" / "logs" / f"{n}.log" for n in ("sleeper", "other")]
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if all(p.exists() and "ready" in p.read_text() for p in logs):
            return
        time.sleep(0.1)
    raise AssertionError("the nodes did not start")


@pytest.mark.parametrize(
    ("sig", "code", "kind"),
    [(signal.SIGTERM, 0, "stopped"), (signal.SIGINT, 0, "stopped"),
     (signal.SIGHUP, E.EXIT_SIGHUP, "SIGHUP")],
)  # fmt: skip
def test_a_signal_to_vigil_launch_writes_run_json(tmp_path, sig, code, kind):
    """SIGTERM (systemd's stop) and SIGINT stop a launch: exit 0 when every node left
    cleanly, run.json says which signal. Before, SIGTERM killed the launcher on the spot
    (no run.json) and its nodes only learnt of it through their parent-death signal."""
    proc = _launch(tmp_path, SLEEP)
    _wait_ready(tmp_path)
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == code, (stdout, stderr)
    record = _run_json(tmp_path / "launch")
    name = signal.Signals(sig).name
    assert record["ending"] == kind and record["cause"].startswith(name)
    assert record["exit_codes"] == {"sleeper": 0, "other": 0}
    assert f"[launch] ended: {record['cause']} (exit {code})" in stdout


@pytest.mark.parametrize(
    ("other", "code", "start"),
    [("import sys\nsys.exit(1)\n", E.EXIT_NODE, "other exited (code 1)"),
     ("import sys\nsys.exit(4)\n", E.EXIT_DISK_FULL,
      "disk full: other exited (code 4, no space left on device)")],
)  # fmt: skip
def test_a_node_death_ends_a_launch_naming_it(tmp_path, other, code, start):
    proc = _launch(tmp_path, other)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == code, (stdout, stderr)
    record = _run_json(tmp_path / "launch")
    assert record["cause"].startswith(start) and record["exit_code"] == code


def test_a_disk_full_node_is_not_restarted(tmp_path):
    from vigil.launch import Launcher
    from vigil.processes import ProcessSpec

    spec = ProcessSpec("full", "", command=[sys.executable, "-c", "import sys; sys.exit(4)"])
    la = Launcher([spec], tmp_path / "logs", max_restarts=3, say=lambda s: None)
    la.start()
    deadline = time.monotonic() + 60
    while la.poll() and time.monotonic() < deadline:
        time.sleep(0.05)
    la.stop(1.0)
    assert la.failures == ["full exited (code 4, no space left on device)"]
    assert E.from_launcher(la) == E.Ending(
        "disk full", "disk full: full exited (code 4, no space left on device)"
    )


def test_exit_codes_are_distinct_per_cause():
    codes = {k: v for k, v in E.KINDS.items() if k not in ("finished", "stopped")}
    assert len(set(codes.values())) == len(codes)
    assert 0 not in codes.values()


def test_run_json_is_written_in_place_and_never_through_a_link(tmp_path):
    target = tmp_path / "precious"
    target.write_text("mine")
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "run.json").symlink_to(target)
    assert not E.write_run_json(tmp_path / "run", {"a": 1}, say=lambda s: None)
    assert target.read_text() == "mine"
    E.write_in_place(tmp_path / "r.json", "x" * 100)
    E.write_in_place(tmp_path / "r.json", "short")
    assert (tmp_path / "r.json").read_text() == "short"


def test_a_signal_during_a_run_stops_vigil_experiments(tmp_path):
    """A run ended by SIGINT/SIGTERM stops the whole set (it used to be a
    KeyboardInterrupt; a RunError of any other cause lets the set go on)."""
    from vigil.experiments import run_set
    from vigil.run import RunError

    calls = []

    def stopped(path, *args, **kwargs):
        calls.append(path.stem)
        raise RunError("SIGTERM: stopped at step 1/5", E.Ending("SIGTERM", "SIGTERM: ..."))

    only = ["empty-room", "occlusion"]
    with pytest.raises(RunError, match="SIGTERM"):
        run_set(REPO / "scenarios" / "guard", tmp_path / "set", only=only, runner=stopped,
                say=lambda s: None)  # fmt: skip
    assert calls == ["empty-room"]
