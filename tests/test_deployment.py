"""Deployment files, scenario files, and the launcher's process handling."""

import os
import sys
import time
from pathlib import Path

import pytest
import yaml

from stack.cells import CellGrid, ConfigError
from vigil.deployment import load_deployment, parse_deployment
from vigil.launch import Launcher, ProcessSpec
from vigil.scenario import load_scenario, parse_scenario

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / "config"


def test_shipped_files_are_valid():
    twin = load_deployment(CONFIG / "twin.yaml")
    assert twin.mode == "twin" and twin.lockstep and twin.ros.localhost_only
    assert twin.task == CONFIG / "task-r2.yaml"
    hw = load_deployment(CONFIG / "hardware.yaml")
    assert hw.mode == "hardware" and not hw.lockstep
    assert hw.hardware["armed"] is False
    for path in sorted((REPO / "scenarios").glob("*.yaml")):
        sc = load_scenario(path)
        assert sc.task.exists() and sc.steps >= 1, path


def base(**changes):
    data = {"mode": "twin", "task": str(CONFIG / "task-r1.yaml")}
    data.update(changes)
    return data


@pytest.mark.parametrize(
    "data, key",
    [
        (base(mode="robot"), "mode"),
        (base(colour="red"), "colour"),
        (base(task="nope.yaml"), "task"),
        (base(lockstep="yes"), "lockstep"),
        (base(twin={"odom_rate_hz": 0}), "twin.odom_rate_hz"),
        (base(twin={"scnee": "x"}), "twin.scnee"),
        (base(planner={"max_steps": -1}), "planner.max_steps"),
        (base(navigation={"pose_source": "gps"}), "navigation.pose_source"),
        (base(hardware={"armed": True}), "hardware"),
        (base(mode="hardware", twin={"seed": 1}), "twin"),
        (base(mode="hardware", lockstep=True), "lockstep"),
        (base(nodes={"stop_timeout_s": 0}), "nodes.stop_timeout_s"),
        (base(nodes={"max_restarts": -2}), "nodes.max_restarts"),
        (base(nodes={"processes": "two"}), "nodes.processes"),
        (base(nodes={"processes": "one"}, lockstep=False), "nodes.processes"),
        (base(mode="hardware", nodes={"processes": "one"}), "nodes.processes"),
        (base(twin={"stall_timeout_s": float("inf")}), "twin.stall_timeout_s"),
        (base(ros={"interfaces": ["10.0.0.300"]}), "ros.interfaces"),
    ],
)
def test_bad_deployments_name_the_key(data, key):
    with pytest.raises(ConfigError) as err:
        parse_deployment(data, None)
    assert err.value.key == key


def test_a_section_built_in_code_is_checked_like_one_read_from_a_file():
    from vigil.deployment import PlannerSection, RosSection

    with pytest.raises(ConfigError, match="nav_timeout_s: nan"):
        PlannerSection(nav_timeout_s=float("nan"))
    with pytest.raises(ConfigError, match="localhost_only.*true or false"):
        RosSection(localhost_only=1)  # type: ignore[arg-type]


def test_hardware_mode_needs_calibration_and_a_valid_stream(tmp_path):
    hw = {"camera_stream": {"url": "rtsp://cam/stream"}}
    with pytest.raises(ConfigError) as err:
        parse_deployment(base(mode="hardware", hardware=hw), None)
    assert err.value.key == "perception.calibration"
    ok = base(mode="hardware", hardware=hw, perception={"calibration": "cal.yaml"})
    ok["ros"] = {"domain_id": 42}
    assert parse_deployment(ok, None).hardware["camera_stream"]["url"] == "rtsp://cam/stream"
    bad = base(mode="hardware", hardware={"camera_stream": {"url": "x", "rate_hz": -1}})
    bad["perception"] = {"calibration": "cal.yaml"}
    bad["ros"] = {"domain_id": 42}
    with pytest.raises(ConfigError):
        parse_deployment(bad, None)


def test_relative_paths_resolve_against_the_file(tmp_path):
    (tmp_path / "task.yaml").write_text((CONFIG / "task-r1.yaml").read_text())
    (tmp_path / "dep.yaml").write_text(yaml.safe_dump({"mode": "twin", "task": "task.yaml"}))
    dep = load_deployment(tmp_path / "dep.yaml")
    assert dep.task == tmp_path / "task.yaml"
    assert dep.resolve("scene.yaml") == tmp_path / "scene.yaml"


def scenario(**changes):
    data = {
        "name": "t",
        "task": str(CONFIG / "task-r1.yaml"),
        "steps": 3,
        "person": {"start": "outside", "walk": [{"to": "door"}, {"to": 1, "pause_s": 2}]},
    }
    data.update(changes)
    return data


def test_scenario_waypoints_in_thesis_terms():
    sc = parse_scenario(scenario())
    grid = CellGrid()
    wps = sc.person_waypoints(grid, door_m=(7.0, 4.0))
    assert wps[0]["x_m"] == 7.0 and wps[0]["y_m"] == pytest.approx(4.0 + 1.2)
    assert wps[1]["y_m"] == pytest.approx(4.0 - 0.8)
    assert (wps[2]["x_m"], wps[2]["y_m"]) == grid.center(1)
    assert wps[2]["pause_s"] == 2


@pytest.mark.parametrize(
    "changes, key",
    [
        ({"steps": 0}, "steps"),
        ({"robot_cell": "seven"}, "robot_cell"),
        ({"belief": {"direction": "up"}}, "belief.direction"),
        ({"person": {"walk": [{"to": "kitchen"}]}}, "person.walk[0].to"),
        ({"person": {"walk": [{"to": 1, "speed_mps": 3.0}]}}, "person.walk[0].speed_mps"),
        ({"faults": [{"kind": "meteor"}]}, "faults[0].kind"),
        ({"faults": [{"kind": "camera_off", "at_s": 1}]}, "faults[0].duration_s"),
        ({"faults": [{"kind": "kill", "node": "planner"}]}, "faults[0]"),
    ],
)
def test_bad_scenarios_name_the_key(changes, key):
    with pytest.raises(ConfigError) as err:
        parse_scenario(scenario(**changes))
    assert err.value.key == key


def test_unknown_cell_in_a_walk_is_refused():
    # refused where it is read (issue 23), against the task's grid, not later in prepare
    with pytest.raises(ConfigError) as err:
        parse_scenario(scenario(person={"walk": [{"to": 40}]}))
    assert err.value.key == "person.walk[0].to"


# -- the launcher ---------------------------------------------------------------------
def sleeper(name, seconds, restart=True, code=0):
    cmd = [sys.executable, "-c", f"import time, sys; time.sleep({seconds}); sys.exit({code})"]
    return ProcessSpec(name, "unused", restart=restart, command=cmd)


def wait_for(cond, timeout=10.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.05)
    return False


def test_launcher_restarts_a_node_then_stops_everything_and_says_which(tmp_path):
    lines = []
    la = Launcher(
        [sleeper("steady", 60), sleeper("flaky", 0.2, code=3)],
        tmp_path,
        max_restarts=2,
        say=lines.append,
    )
    la.start()
    assert wait_for(lambda: not la.poll())
    assert la.stopped_because == "flaky exited (code 3)"
    assert sum("restarting" in line for line in lines) == 2
    assert la.exit_codes["flaky"] == 3
    assert la.exit_codes["steady"] is not None  # stopped by the launcher
    assert (tmp_path / "flaky.log").read_text().count("--- restart") == 2


def test_nodes_die_with_a_killed_launcher(tmp_path):
    import os
    import signal
    import subprocess

    code = (
        f"import sys, time; sys.path.insert(0, {str(REPO)!r});"
        "from vigil.launch import Launcher, ProcessSpec;"
        "la = Launcher([ProcessSpec('s', 'x', command=[sys.executable, '-c',"
        f" 'import time; time.sleep(60)'])], {str(tmp_path)!r}, say=lambda s: 0);"
        "la.start(); print(la.pids()['s'], flush=True); time.sleep(60)"
    )
    launcher = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    child = int(launcher.stdout.readline())
    launcher.send_signal(signal.SIGKILL)  # no chance to clean up
    launcher.wait()

    def gone():
        try:
            os.kill(child, 0)
        except ProcessLookupError:
            return True
        # a zombie until reaped by init counts as gone
        return open(f"/proc/{child}/stat").read().split()[2] == "Z"

    assert wait_for(gone, timeout=10.0)


def test_a_restart_waits_its_delay_and_the_node_is_absent_meanwhile(tmp_path):
    """``nodes.restart_delay_s``: a killed node is not running until its delay has
    passed, then comes back with a new pid, said in the launcher's started-line."""
    lines: list[str] = []
    la = Launcher([sleeper("a", 60)], tmp_path, say=lines.append, restart_delay_s=1.0)
    la.start()
    first = la.pids()["a"]
    la.kill("a")
    assert wait_for(lambda: la.poll() and "a" in la.waiting)
    t_exit = time.monotonic()
    assert "a" not in la.running and "a" not in la.pids()
    assert wait_for(lambda: la.poll() and "a" in la.running)
    assert time.monotonic() - t_exit >= 0.9  # not before its delay
    assert la.pids()["a"] != first
    assert any(line.endswith("restarting (1/3) in 1 s") for line in lines), lines
    assert any(line.startswith("[launch] started a (pid ") for line in lines[2:]), lines
    la.stop(timeout_s=2.0)
    assert la.waiting == {} and la.running == {}


def test_launcher_stop_and_kill(tmp_path):
    la = Launcher([sleeper("a", 60), sleeper("b", 60, restart=False)], tmp_path, say=lambda s: 0)
    la.start()
    first = la.pids()["a"]
    la.kill("a")
    assert wait_for(lambda: la.poll() and la.pids()["a"] != first)
    codes = la.stop(timeout_s=2.0)
    assert set(codes) == {"a", "b"} and all(c is not None for c in codes.values())
    assert la.running == {}


# -- the system a deployment makes --------------------------------------------------
def hardware_deployment(tmp_path) -> dict:
    """config/hardware.yaml with task r2, and an empty policy and calibration in tmp_path."""
    (tmp_path / "cal.yaml").write_text("unused: true\n")
    (tmp_path / "policy.npz").write_bytes(b"")
    data = yaml.safe_load((CONFIG / "hardware.yaml").read_text())
    data.update(
        task=str(CONFIG / "task-r2.yaml"),
        policy=str(tmp_path / "policy.npz"),
        perception={"calibration": str(tmp_path / "cal.yaml")},
    )
    return data


def test_hardware_system_gates_motion_and_has_no_twin(tmp_path):
    from vigil.system import prepare

    data = hardware_deployment(tmp_path)
    dep = parse_deployment(data, tmp_path / "hardware.yaml")
    system = prepare(dep, tmp_path / "run", say=lambda s: None)
    names = [s.name for s in system.specs]
    assert "twin_bridge" not in names
    assert {"camera_stream", "velocity_gate", "planner", "navigation"} <= set(names)
    p = system.params
    assert p["navigation"]["cmd_vel_topic"] == "/nav/cmd_vel"  # only the gate drives
    assert p["velocity_gate"]["output_topic"] == "/cmd_vel"
    assert p["velocity_gate"]["armed"] is False
    assert p["navigation"]["pose_source"] == "amcl"
    # no node takes /odom for the map pose on a robot: the map pose comes through TF
    assert p["legs"]["pose_source"] == p["observations"]["pose_source"] == "tf"
    assert p["localisation"]["publish_map_odom"] is False  # the robot's localisation does
    assert not any(v.get("lockstep") for v in p.values())
    assert "192.168.1.10" in Path(system.env["FASTDDS_DEFAULT_PROFILES_FILE"]).read_text()
    stack_cfg = yaml.safe_load((tmp_path / "run" / "stack.yaml").read_text())
    assert stack_cfg["speech"]["restricted_cells"] == [1, 12]  # the task's, for the warning
    params = yaml.safe_load((tmp_path / "run" / "params.yaml").read_text())
    assert params["planner"]["ros__parameters"]["task_file"].endswith("task-r2.yaml")


def twin_data(tmp_path) -> dict:
    """config/twin.yaml with task r1, an empty policy in tmp_path and absolute paths."""
    (tmp_path / "policy.npz").write_bytes(b"")
    data = yaml.safe_load((CONFIG / "twin.yaml").read_text())
    data.update(task=str(CONFIG / "task-r1.yaml"), policy=str(tmp_path / "policy.npz"))
    data["twin"]["scene"] = str(CONFIG / "twin-scene.yaml")
    return data


def test_twin_system_is_lockstep_on_localhost(tmp_path, monkeypatch):
    from vigil.system import prepare

    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "3")  # the user's choice is kept

    data = twin_data(tmp_path)
    dep = parse_deployment(data, tmp_path / "twin.yaml")
    scenario = load_scenario(REPO / "scenarios" / "5.1.2.yaml")
    system = prepare(dep, tmp_path / "run", scenario, say=lambda s: None)
    p = system.params
    assert p["twin_bridge"]["lockstep"] is True
    # every node takes part in the lock-step but the viewer's markers, which only draw
    # (the bag too: it holds every message in its lock-step phase, for vigil replay-bag)
    assert set(p["twin_bridge"]["participants"]) == {s.name for s in system.specs} - {
        "twin_bridge",
        "markers",
    }
    assert p["bag"]["lockstep"] is True and "bag" not in p["bag"]["participants"]
    assert {"markers", "bag"} <= {s.name for s in system.specs}
    assert (
        "<address>127.0.0.1</address></interfaceWhiteList>"
        in Path(system.env["FASTDDS_DEFAULT_PROFILES_FILE"]).read_text()
    )
    twin = yaml.safe_load((tmp_path / "run" / "twin.yaml").read_text())["twin"]
    assert twin["robot"]["start_cell"] == scenario.robot_cell
    assert len(twin["person"]["waypoints"]) == len(scenario.walk) + 1
    assert (tmp_path / "run" / "calibration.yaml").exists()  # from the twin's floor points
    assert p["planner"]["max_steps"] == scenario.steps
    # one BLAS thread a node: a dozen processes share the cores
    assert system.env["OPENBLAS_NUM_THREADS"] == "1" and "OMP_NUM_THREADS" not in system.env
    # the twin's TF: the localisation stand-in publishes map -> odom and the camera frames
    assert p["localisation"]["publish_map_odom"] is True
    assert p["localisation"]["calibration_file"].endswith("calibration.yaml")
    assert p["legs"]["pose_source"] == p["observations"]["pose_source"] == "odom"


def test_a_realtime_twin_runs_free_writes_its_stats_and_its_nodes_yield_the_cores(tmp_path):
    from vigil.system import REALTIME_NODES_NICE, prepare

    data = twin_data(tmp_path)
    lockstep = prepare(parse_deployment(data, tmp_path / "twin.yaml"), tmp_path / "a",
                       say=lambda s: None)  # fmt: skip
    assert all(s.nice == 0 for s in lockstep.specs)
    assert lockstep.params["twin_bridge"]["realtime_file"] == ""
    data.update(lockstep=False)
    data["twin"]["realtime"] = True
    system = prepare(parse_deployment(data, tmp_path / "twin.yaml"), tmp_path / "b",
                     say=lambda s: None)  # fmt: skip
    bridge = system.params["twin_bridge"]
    assert bridge["realtime"] is True and bridge["lockstep"] is False
    assert bridge["realtime_file"] == str(tmp_path / "b" / "realtime.json")
    assert system.params["bag"]["sim_clock"] is False  # the system clock, as on a robot
    # the world starts once every node is up
    assert set(bridge["participants"]) == {s.name for s in system.specs} - {"twin_bridge"}
    assert lockstep.params["bag"]["sim_clock"] is True
    nice = {s.name: s.nice for s in system.specs}
    assert nice.pop("twin_bridge") == 0
    assert set(nice.values()) == {REALTIME_NODES_NICE} and REALTIME_NODES_NICE > 0


def test_a_twin_with_the_velocity_gate_puts_it_between_navigation_and_the_base(tmp_path):
    """twin.velocity_gate: the hardware chain in the twin, at real time only."""
    from vigil.system import prepare

    data = twin_data(tmp_path)
    data["twin"]["velocity_gate"] = True
    with pytest.raises(ConfigError, match=r"twin\.velocity_gate.*real time"):
        prepare(parse_deployment(data, tmp_path / "twin.yaml"), tmp_path / "a",
                say=lambda s: None)  # fmt: skip
    assert not (tmp_path / "a").exists()  # refused before the run folder is made
    data.update(lockstep=False)
    data["twin"]["realtime"] = True
    system = prepare(parse_deployment(data, tmp_path / "twin.yaml"), tmp_path / "b",
                     say=lambda s: None)  # fmt: skip
    p = system.params
    assert "velocity_gate" in {s.name for s in system.specs}
    assert p["navigation"]["cmd_vel_topic"] == p["velocity_gate"]["input_topic"] == "/nav/cmd_vel"
    assert p["velocity_gate"]["output_topic"] == "/cmd_vel" and p["velocity_gate"]["armed"]
    # the twin's base watches the gate's heartbeat; the world waits for the gate too
    assert 0 < p["twin_bridge"]["gate_heartbeat_timeout_s"] < 0.5
    assert "velocity_gate" in p["twin_bridge"]["participants"]
    # capped at the twin base's own limits: the gate adds its timeout, not a slower robot
    caps = yaml.safe_load(Path(p["velocity_gate"]["config_file"]).read_text())["velocity_gate"]
    from twin.config import TwinConfig

    scene = yaml.safe_load((tmp_path / "b" / "twin.yaml").read_text())["twin"]
    robot = TwinConfig.from_dict(scene).robot
    assert caps["max_linear_mps"] == robot.max_linear_mps
    assert caps["max_angular_accel_radps2"] == robot.max_angular_accel_radps2
    assert caps["require_arming"] is False
    # without the gate navigation drives the base itself
    data["twin"]["velocity_gate"] = False
    plain = prepare(parse_deployment(data, tmp_path / "twin.yaml"), tmp_path / "c",
                    say=lambda s: None)  # fmt: skip
    assert plain.params["navigation"]["cmd_vel_topic"] == "/cmd_vel"
    assert "velocity_gate" not in plain.params
    assert "gate_heartbeat_timeout_s" not in plain.params["twin_bridge"]


def test_a_spec_s_niceness_reaches_its_process(tmp_path):
    code = "import os; print('niceness', os.nice(0), flush=True); import time; time.sleep(30)"
    base = os.nice(0)
    la = Launcher(
        [ProcessSpec("n", "x", command=[sys.executable, "-c", code], nice=3)],
        tmp_path,
        say=lambda s: None,
    )
    la.start()
    log = tmp_path / "n.log"
    assert wait_for(lambda: log.exists() and "niceness" in log.read_text())
    la.stop(timeout_s=2.0)
    assert f"niceness {min(base + 3, 19)}" in log.read_text()


def test_twin_with_tf_pose_source_gives_every_consumer_tf(tmp_path):
    from vigil.system import prepare

    (tmp_path / "policy.npz").write_bytes(b"")
    data = yaml.safe_load((CONFIG / "twin-tf.yaml").read_text())
    data.update(task=str(CONFIG / "task-r1.yaml"), policy=str(tmp_path / "policy.npz"))
    data["twin"] = {"scene": str(CONFIG / "twin-scene.yaml")}
    dep = parse_deployment(data, tmp_path / "twin-tf.yaml")
    p = prepare(dep, tmp_path / "run", say=lambda s: None).params
    assert p["navigation"]["pose_source"] == "tf"
    assert p["legs"]["pose_source"] == p["observations"]["pose_source"] == "tf"


def test_hardware_refuses_odometry_as_the_map_pose(tmp_path):
    data = yaml.safe_load((CONFIG / "hardware.yaml").read_text())
    data["navigation"] = {**data.get("navigation", {}), "pose_source": "odom"}
    with pytest.raises(ConfigError, match="navigation.pose_source.*amcl or tf"):
        parse_deployment(data, tmp_path / "hardware.yaml")


def test_hardware_camera_info_reaches_the_camera_node_and_a_bad_one_stops_the_deployment(
    tmp_path,
):
    from vigil.system import prepare

    data = hardware_deployment(tmp_path)
    data["hardware"]["camera_info"] = "intrinsics.yaml"  # relative to the deployment file
    (tmp_path / "intrinsics.yaml").write_text(
        "width: 640\nheight: 400\nK: [500, 0, 319.5, 0, 500, 199.5, 0, 0, 1]\n"
    )
    dep = parse_deployment(data, tmp_path / "hardware.yaml")
    system = prepare(dep, tmp_path / "run", say=lambda s: None)
    assert system.params["camera_stream"]["camera_info_file"] == str(tmp_path / "intrinsics.yaml")
    (tmp_path / "intrinsics.yaml").write_text("width: 640\nheight: 400\n")  # no K
    with pytest.raises(ConfigError) as err:
        parse_deployment(data, tmp_path / "hardware.yaml")
    assert err.value.key == "hardware.camera_info"
    data["hardware"]["camera_info"] = 3
    with pytest.raises(ConfigError, match="must be a path"):
        parse_deployment(data, tmp_path / "hardware.yaml")


# -- the system over several hosts ----------------------------------------------------
def split_twin(tmp_path, hosts, **extra) -> dict:
    data = twin_data(tmp_path)
    data["twin"]["realtime"] = True
    data.update({"lockstep": False, "hosts": hosts, **extra})
    return data


HOSTS = {
    "robot": ["twin_bridge", "localisation", "legs", "navigation", "speech"],
    "camera": ["camera_people"],
    "planner": ["observations", "planner", "recorder", "bag", "markers"],
}


def test_each_host_starts_its_own_nodes(tmp_path):
    from vigil.system import host_specs, prepare

    dep = parse_deployment(split_twin(tmp_path, HOSTS), tmp_path / "twin.yaml")
    system = prepare(dep, tmp_path / "run", say=lambda s: None)
    assert [s.name for s in host_specs(system, dep, "camera")] == ["camera_people"]
    robot = {s.name for s in host_specs(system, dep, "robot")}
    assert robot == set(HOSTS["robot"])
    assert len(host_specs(system, dep, None)) == len(system.specs)
    with pytest.raises(ConfigError, match="--host.*not a host"):
        host_specs(system, dep, "kitchen")
    bad = parse_deployment(split_twin(tmp_path, {"robot": ["twin_brige"]}), tmp_path / "t.yaml")
    with pytest.raises(ConfigError, match=r"hosts\.robot.*twin_brige"):
        host_specs(prepare(bad, tmp_path / "run2", say=lambda s: None), bad, "robot")
    # a node on no host would run nowhere: the twin's velocity gate left out, say
    gated = split_twin(tmp_path, HOSTS)
    gated["twin"]["velocity_gate"] = True
    dep = parse_deployment(gated, tmp_path / "gated.yaml")
    system = prepare(dep, tmp_path / "run3", say=lambda s: None)
    with pytest.raises(ConfigError, match=r"hosts.*velocity_gate.*on no host"):
        host_specs(system, dep, "robot")


@pytest.mark.parametrize(
    "hosts, extra, match",
    [
        ({"robot": ["planner"], "pc": ["planner"]}, {}, "already runs on host 'robot'"),
        ({"robot": "planner"}, {}, r"hosts\.robot.*list of node names"),
        (["robot"], {}, "must map host names"),
        ({"the robot": ["planner"]}, {}, "host names are words"),
        ({"robot": ["planner"]}, {"lockstep": True}, "cannot run in lock-step"),
    ],
)
def test_bad_hosts_are_refused_by_key(tmp_path, hosts, extra, match):
    with pytest.raises(ConfigError, match=match):
        parse_deployment(split_twin(tmp_path, hosts, **extra), tmp_path / "twin.yaml")


def test_peers_are_asked_at_discovery_and_need_the_network(tmp_path):
    from vigil.dds import profile_xml

    ros = {"domain_id": 77, "localhost_only": False, "interfaces": ["10.77.0.2"],
           "peers": ["10.77.0.1", "10.77.0.3"]}  # fmt: skip
    dep = parse_deployment(split_twin(tmp_path, HOSTS, ros=ros), tmp_path / "twin.yaml")
    assert dep.ros.peers == ("10.77.0.1", "10.77.0.3")
    xml = profile_xml(dep.ros.interfaces, dep.ros.peers)
    peers_list = xml.split("<initialPeersList>")[1].split("</initialPeersList>")[0]
    assert all(ip in peers_list for ip in ("127.0.0.1", "10.77.0.2", "10.77.0.1", "10.77.0.3"))
    white = xml.split("<interfaceWhiteList>")[1].split("</interfaceWhiteList>")[0]
    assert "10.77.0.1" not in white  # a peer is asked, not listened on
    with pytest.raises(ConfigError, match="peers.*localhost_only: false"):
        parse_deployment(
            split_twin(tmp_path, HOSTS, ros={"localhost_only": True, "peers": ["10.0.0.1"]}),
            tmp_path / "twin.yaml",
        )
    with pytest.raises(ConfigError, match="peers"):
        parse_deployment(
            split_twin(tmp_path, HOSTS, ros={"localhost_only": False, "peers": ["10.0.0"]}),
            tmp_path / "twin.yaml",
        )


def test_a_lockstep_twin_run_s_nodes_go_in_one_process_where_they_can(tmp_path):
    """Issue 25: vigil run puts the lock-step twin's nodes in one process
    (vigil.container), the same nodes with the same parameters; a scenario that kills a
    node, a real-time twin or the nodes spread over hosts keep a process a node, and
    asking for one process there is refused by name."""
    from vigil.container import NODES, one_process
    from vigil.system import prepare

    data = twin_data(tmp_path)
    dep = parse_deployment(data, tmp_path / "twin.yaml")
    plain = parse_scenario(scenario(), tmp_path / "s.yaml")
    system = prepare(dep, tmp_path / "a", plain, say=lambda s: None)
    one = one_process(dep, system, plain, say=lambda s: None)
    assert [s.name for s in one.specs] == ["container"]
    (spec,) = one.specs
    assert spec.restart is False  # one failure domain: a node that fails ends the run
    argv = spec.argv()
    assert argv[argv.index("--nodes") + 1].split(",") == [s.name for s in system.specs]
    assert argv[-2:] == ["--params-file", str(system.specs[0].params_file)]
    assert {s.name for s in system.specs} <= set(NODES)
    assert one.env == system.env
    # the same parameters, and the bridge renders a frame beside the nodes
    assert one.params == {
        **system.params,
        "twin_bridge": {**system.params["twin_bridge"], "render_ahead": True},
    }
    written = yaml.safe_load(system.specs[0].params_file.read_text())
    assert written["twin_bridge"]["ros__parameters"]["render_ahead"] is True

    kill = parse_scenario(
        scenario(faults=[{"kind": "kill", "node": "planner", "after_step": 1}]), tmp_path / "k.yaml"
    )
    assert one_process(dep, system, kill) is system  # auto: a process a node
    data["nodes"]["processes"] = "one"
    asked = parse_deployment(data, tmp_path / "twin.yaml")
    with pytest.raises(ConfigError, match="kills planner") as err:
        one_process(asked, system, kill)
    assert err.value.key == "nodes.processes"
    data["nodes"]["processes"] = "separate"
    separate = parse_deployment(data, tmp_path / "twin.yaml")
    assert one_process(separate, system, plain) is system

    data["nodes"]["processes"] = "auto"
    data.update(lockstep=False)
    data["twin"]["realtime"] = True
    realtime = parse_deployment(data, tmp_path / "twin.yaml")
    rt_system = prepare(realtime, tmp_path / "b", plain, say=lambda s: None)
    assert one_process(realtime, rt_system, plain) is rt_system
    data["nodes"]["processes"] = "one"
    with pytest.raises(ConfigError, match="lock-step twin run only"):
        parse_deployment(data, tmp_path / "twin.yaml")


def test_the_container_s_log_is_split_by_node(tmp_path):
    from vigil.container import split_log

    (tmp_path / "container.log").write_text(
        "[INFO] [1.5] [planner]: step 1\n"
        "[WARN] [1.6] [twin_bridge]: lock-step: slow\n"
        "Traceback (most recent call last):\n"
        "[INFO] [1.7] [planner]: step 2\n"
    )
    split_log(tmp_path, ["twin_bridge", "planner", "bag"])
    assert (tmp_path / "planner.log").read_text().splitlines() == [
        "[INFO] [1.5] [planner]: step 1",
        "[INFO] [1.7] [planner]: step 2",
    ]
    assert "slow" in (tmp_path / "twin_bridge.log").read_text()
    assert (tmp_path / "bag.log").read_text() == ""


def test_the_container_refuses_a_node_it_does_not_know(tmp_path):
    import subprocess

    out = subprocess.run(
        [sys.executable, "-m", "vigil.container", "--nodes", "twin_bridge,kettle"],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=120,
    )
    assert out.returncode == 2
    assert "[FATAL] container:" in out.stderr and "'kettle'" in out.stderr
