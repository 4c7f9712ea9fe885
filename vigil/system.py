"""The networked system of figure 4.7 as processes: which nodes, with which parameters.

:func:`prepare` turns a deployment file (and optionally a scenario) into a run folder
holding everything the nodes read (the twin's scene with the scenario's person, the
stack's config with the task's grid, the camera calibration, the policy, one ROS
parameters file) and the list of :class:`vigil.launch.ProcessSpec` to start.

Twin mode: twin_bridge + localisation, camera_people, legs, observations, navigation, speech,
planner, recorder (lock-step participants). Hardware mode: camera_stream and
velocity_gate instead of the bridge; the robot's own drivers provide /scan and the
pose, navigation drives ``/nav/cmd_vel`` through the gate, and nothing moves until the
operator arms the gate.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import stack.topics as topic
from stack.cells import CellGrid, ConfigError
from stack.config import dump_yaml, read_yaml, write_text
from stack.files import make_dir
from stack.memo import Memo
from stack.planning.threads import ENV_VARS as BLAS_THREAD_VARS
from twin.realtime import REALTIME_FILE
from vigil.dds import deployment_env
from vigil.deployment import Deployment, gate_topics
from vigil.processes import ProcessSpec
from vigil.scenario import Scenario
from vigil.security import security_env

REPO = Path(__file__).resolve().parents[1]
POLICY_CACHE = REPO / "runs" / ".policies"
LIDAR_X_M = 0.24  # the twin's lidar site on the MBot (twin/assets/mbot.xml)
REALTIME_NODES_NICE = 5  # the nodes' niceness beside a real-time twin (ProcessSpec.nice)

MODULES = {
    "twin_bridge": "twin.bridge_node",
    "camera_stream": "stack.hardware.node_camera_stream",
    "velocity_gate": "stack.hardware.node_velocity_gate",
    "camera_people": "stack.perception.node_camera_people",
    "localisation": "stack.nav.node_localisation",
    "legs": "stack.perception.node_legs",
    "observations": "stack.perception.node_observations",
    "navigation": "stack.nav.node_navigation",
    "speech": "stack.nav.node_speech",
    "planner": "stack.planning.node_planner",
    "recorder": "vigil.node_recorder",
    "table_player": "vigil.node_table_player",
    "markers": "vigil.node_markers",
    "bag": "vigil.node_bag",
}


@dataclass
class System:
    """A prepared run: its folder, its processes and what they were given."""

    run_dir: Path
    specs: list[ProcessSpec]
    params: dict[str, dict[str, Any]]
    env: dict[str, str] = field(default_factory=dict)
    max_steps: int = 0


def policy_for(task_path: Path, say=print, iterations: int = 200) -> Path:
    """The task's policy, solved once and cached by the task file's content."""
    from stack.planning.policy_cache import cached_task_policy
    from stack.planning.solve import TASK_CONFIG

    config = replace(TASK_CONFIG, iterations=iterations)
    return cached_task_policy(task_path, POLICY_CACHE, config, say)


def _twin_gate(dep: Deployment, twin_cfg, run_dir: Path) -> dict[str, Any]:
    """The velocity gate's parameters in a twin run (``twin.velocity_gate``): armed from
    the start (no operator), capped at what the twin's base can do (its speeds and
    accelerations), so the gate changes nothing but what a robot's gate adds: its stale
    timeout, its heartbeat and a process between navigation and the base that can die."""
    from stack.hardware.velocity_gate import GateConfig

    robot = twin_cfg.robot
    caps = {
        "max_linear_mps": robot.max_linear_mps,
        "max_angular_radps": robot.max_angular_radps,
        "max_linear_accel_mps2": robot.max_linear_accel_mps2,
        "max_angular_accel_radps2": robot.max_angular_accel_radps2,
        "require_arming": False,
    }
    GateConfig.from_dict(caps, "velocity_gate")  # a base beyond the platform's limits: refused
    gate_file = run_dir / "velocity_gate.yaml"
    write_text(gate_file, dump_yaml({"velocity_gate": caps}, sort_keys=True))
    return {"config_file": str(gate_file), "armed": True, **gate_topics(dep)}


def _read_yaml(path: Path | None) -> dict[str, Any]:
    return {} if path is None else read_yaml(path)


def prepare(
    dep: Deployment,
    run_dir: Path,
    scenario: Scenario | None = None,
    seed: int | None = None,
    say=print,
) -> System:
    """Write the run folder's inputs and return the processes to start.

    Raises:
        ConfigError: a file the deployment names is missing or invalid.
    """
    from twin.config import TwinConfig

    twin_gate = dep.mode == "twin" and dep.twin.velocity_gate
    if twin_gate and not realtime_twin(dep):
        raise ConfigError(
            "twin.velocity_gate", True, "the gate keeps the wall clock: it needs the twin at "
            "real time (vigil run --realtime, or lockstep: false and twin.realtime: true)",
        )  # fmt: skip
    run_dir = Path(run_dir).resolve()
    run_dir.mkdir(parents=True, exist_ok=True)
    make_dir(run_dir / "speech")  # a link planted under the name is refused
    task = scenario.task if scenario is not None else dep.task
    task_data = read_yaml(task)
    grid_section = task_data.get("grid")
    grid = CellGrid.from_mapping(grid_section) if grid_section else CellGrid()
    seed = seed if seed is not None else (scenario.seed if scenario else dep.twin.seed)

    # the stack's config: the task's grid + perception and navigation sections
    stack_cfg: dict[str, Any] = {}
    for extra in (dep.resolve(dep.perception.config), dep.resolve(dep.navigation.config)):
        stack_cfg.update(_read_yaml(extra))
    if grid_section:
        stack_cfg["grid"] = grid_section
    # the base's drive: the follower steers for it (and the twin's base is built so)
    stack_cfg["follower"] = {**stack_cfg.get("follower", {}), "drive": dep.navigation.drive}
    # speech warns in the task's restricted cells (not the node's default)
    restricted = list(task_data.get("restricted_cells", []))
    if restricted:
        stack_cfg["speech"] = {**stack_cfg.get("speech", {}), "restricted_cells": restricted}
    people = int(task_data.get("people", 1))
    if people > 1:  # issue 16: the camera reports everyone, the observations per slot
        stack_cfg["camera"] = {**stack_cfg.get("camera", {}), "max_people": people}
    stack_file = run_dir / "stack.yaml"
    write_text(stack_file, dump_yaml(stack_cfg, sort_keys=True))

    policy = _policy(dep, task, people, say)
    common = {"lockstep": dep.lockstep, "use_sim_time": False}
    params: dict[str, dict[str, Any]] = {}
    twin_mode = dep.mode == "twin"
    if twin_mode:
        scene = _read_yaml(dep.resolve(dep.twin.scene))
        scene = dict(scene.get("twin", scene))
        if grid_section:
            scene["grid"] = grid_section
        scene["robot"] = {**scene.get("robot", {}), "drive": dep.navigation.drive}
        faults = scenario.faults if scenario else ()
        if scenario is not None:
            scene.setdefault("robot", {})
            scene["robot"] = {**scene["robot"], "start_cell": scenario.robot_cell}
            obstacles = [
                {"x_m": grid.center(f.cell)[0], "y_m": grid.center(f.cell)[1]}
                for f in faults
                if f.kind == "obstacle"
            ]
            if obstacles:
                scene["obstacles"] = obstacles
            from twin.scene import layout_of

            door_m = layout_of(TwinConfig.from_dict(scene)).door_center_m
            scene.update(scene_people(scene, scenario, grid, door_m))
        twin_file = run_dir / "twin.yaml"
        write_text(twin_file, dump_yaml({"twin": scene}, sort_keys=False))
        twin_cfg = TwinConfig.from_dict(scene)
        outages = [
            [f.kind.split("_")[0], f.at_s, f.at_s + f.duration_s]
            for f in faults
            if f.kind in ("camera_off", "lidar_off")
        ]
        calibration = dep.resolve(dep.perception.calibration)
        if calibration is None:
            calibration = run_dir / "calibration.yaml"
            _calibrate_twin(twin_cfg, calibration, say)
        params["twin_bridge"] = {
            "config": str(twin_file),
            "seed": seed,
            "realtime": dep.twin.realtime,
            # how well a real-time twin kept the wall clock: summary.json's "realtime"
            "realtime_file": str(run_dir / REALTIME_FILE) if realtime_twin(dep) else "",
            "odom_rate_hz": dep.twin.odom_rate_hz,
            "lockstep": dep.lockstep,
            "stall_timeout_s": dep.twin.stall_timeout_s,
            "stall_abort_s": dep.twin.stall_abort_s or 3 * dep.twin.stall_timeout_s,
            "sensor_outages": json.dumps(outages),
        }
        if twin_gate:  # the hardware chain: navigation -> gate -> the twin's base
            params["velocity_gate"] = _twin_gate(dep, twin_cfg, run_dir)
            params["twin_bridge"]["gate_heartbeat_timeout_s"] = GATE_HEARTBEAT_TIMEOUT_S
    else:
        calibration = dep.resolve(dep.perception.calibration)
        hw_file = run_dir / "hardware.yaml"
        write_text(hw_file, dump_yaml(dep.hardware, sort_keys=True))
        params["camera_stream"] = {"config_file": str(hw_file)}
        info = dep.resolve(dep.hardware.get("camera_info", ""))
        if info is not None:  # the camera's intrinsics: /camera/camera_info beside the images
            params["camera_stream"]["camera_info_file"] = str(info)
        params["velocity_gate"] = {
            "config_file": str(hw_file),
            "armed": bool(dep.hardware.get("armed", False)),
            **gate_topics(dep),  # the topics vigil arm/disarm/status use too
        }

    cfg = str(stack_file)
    params["camera_people"] = {**common, "config_file": cfg, "calibration_file": str(calibration)}
    # TF: the camera's static frames; in the twin also map -> odom (on a robot its own
    # localisation, e.g. AMCL, publishes map -> odom)
    # the robot's map pose for legs and observations: through TF on a robot (map -> odom
    # from its localisation) and in the twin when navigation takes it so; else /odom (the
    # twin's odom frame is the map frame at the start)
    tf_pose = not twin_mode or dep.navigation.pose_source == "tf"
    map_pose_source = "tf" if tf_pose else "odom"
    params["localisation"] = {
        **common,
        "calibration_file": str(calibration) if calibration else "",
        "publish_map_odom": twin_mode,
        "odom_topic": dep.topics.odom,
    }
    params["legs"] = {
        **common,
        "config_file": cfg,
        "scan_topic": dep.topics.scan,
        "odom_topic": dep.topics.odom,
        "laser_x_m": LIDAR_X_M if twin_mode else 0.0,
        "pose_source": map_pose_source,
    }
    params["observations"] = {
        **common,
        "config_file": cfg,
        "calibration_file": str(calibration),  # the cells the robot hides from the camera
        "odom_topic": dep.topics.odom,
        "pose_source": map_pose_source,
        "decision_period_s": 0.25,  # continuous: speech and the planner's events read it
    }
    if people > 1:
        params["observations"]["people"] = people
    params["navigation"] = {
        **common,
        "config_file": cfg,
        "pose_source": dep.navigation.pose_source,
        "pose_topic": dep.navigation.pose_topic,
        "control_rate_hz": dep.navigation.control_rate_hz,
        "cmd_vel_topic": topic.CMD_VEL if twin_mode and not twin_gate else topic.NAV_CMD_VEL,
    }
    params["speech"] = {
        **common,
        "config_file": cfg,
        "voice": dep.speech.voice,
        "out_dir": str(run_dir / "speech"),
    }
    max_steps = scenario.steps if scenario else dep.planner.max_steps
    planner = {
        **common,
        "task_file": str(task),
        "policy_file": str(policy),
        "state_file": str(run_dir / "planner_state.json"),
        "steps_file": str(run_dir / "steps.jsonl"),
        "max_steps": max_steps,
        "start_delay_s": dep.planner.start_delay_s,
        "nav_timeout_s": dep.planner.nav_timeout_s,
        "obs_timeout_s": dep.planner.obs_timeout_s,
        "min_step_s": 2.5,
        "min_event_step_s": 1.5,  # a person in a new cell ends a step this soon
    }
    if scenario is not None:
        planner.update(
            initial_robot_cell=scenario.robot_cell,
            initial_person_cell=scenario.belief_person or 0,
            initial_direction=scenario.belief_direction,
        )
    params["planner"] = planner
    params["recorder"] = {
        **common,
        "out_dir": str(run_dir),
        "task_file": str(task),
        "config_file": cfg,
    }

    names = ["twin_bridge"] if twin_mode else ["camera_stream", "velocity_gate"]
    names += ["velocity_gate"] if twin_gate else []
    names += ["localisation", "camera_people", "legs", "observations", "navigation", "speech"]
    names += ["planner"]
    names += ["recorder"]
    if twin_mode and dep.lockstep:
        params["twin_bridge"]["participants"] = [n for n in names if n != "twin_bridge"]
    # the viewer's markers (RViz, Foxglove): no lock-step participant, it only draws
    params["markers"] = {"task_file": str(task)}
    names.append("markers")
    # the run's rosbag2 bag (MCAP): with lock-step a participant (it only listens, but the
    # twin waits for it, so every message is in the bag in its lock-step phase: what
    # vigil replay-bag re-enacts); without lock-step it only listens
    # log times: the twin's /clock in lock-step; the system clock in real time (as on a
    # robot: the twin's stamps are on it too)
    sim_clock = twin_mode and not realtime_twin(dep)
    params["bag"] = {"out_dir": str(run_dir), "camera_period_s": 1.0, "sim_clock": sim_clock}
    if twin_mode and dep.lockstep:
        params["bag"].update(
            lockstep=True, participants=list(params["twin_bridge"]["participants"])
        )
        params["twin_bridge"]["participants"].append("bag")
    names.append("bag")
    if realtime_twin(dep):  # the world starts once every node is up (on any host)
        params["twin_bridge"]["participants"] = [n for n in names if n != "twin_bridge"]
    return _write(run_dir, names, params, dep, max_steps)


def prepare_table(dep: Deployment, run_dir: Path, scenario: Scenario, say=print) -> System:
    """Planner + table player: the thesis's table as the observations."""
    if not scenario.thesis_table:
        raise ConfigError("thesis_table", "", "the scenario names no thesis table")
    policy = _policy(dep, scenario.task, int(read_yaml(scenario.task).get("people", 1)), say)
    params = {
        "planner": {
            "lockstep": False,
            "task_file": str(scenario.task),
            "policy_file": str(policy),
            "state_file": str(run_dir / "planner_state.json"),
            "steps_file": str(run_dir / "steps.jsonl"),
            "max_steps": scenario.steps,
            "start_delay_s": dep.planner.start_delay_s,  # the deployment's, as in the twin
            "min_step_s": 0.0,
            "initial_robot_cell": scenario.robot_cell,
            "initial_person_cell": scenario.belief_person or 0,
            "initial_direction": scenario.belief_direction,
        },
        "table_player": {"table": scenario.thesis_table},
    }
    dep = replace(dep, lockstep=False)
    return _write(run_dir, ["planner", "table_player"], params, dep, scenario.steps)


def _policy(dep: Deployment, task: Path, people: int, say) -> Path | str:
    """The policy file of a one-person task; "" with several people (the planner node
    plans online, issue 16)."""
    if people > 1:
        return ""
    return dep.policy or policy_for(task, say)


def write_params(run_dir: Path, names: list[str], params: dict) -> Path:
    """The nodes' parameters, one section a node, in ``run_dir/params.yaml``."""
    params_file = run_dir / "params.yaml"
    doc = {name: {"ros__parameters": params[name]} for name in names}
    write_text(params_file, dump_yaml(doc, sort_keys=True))
    return params_file


def _write(
    run_dir: Path, names: list[str], params: dict, dep: Deployment, max_steps: int
) -> System:
    params_file = write_params(run_dir, names, params)
    # a real-time twin stands for the physical world, which never waits: the nodes
    # yield the cores to it (on a robot they have cores of their own)
    realtime = realtime_twin(dep)
    specs = [
        ProcessSpec(
            name,
            MODULES[name],
            params_file,
            restart=dep.nodes.restart and name not in ("twin_bridge", "recorder"),
            nice=REALTIME_NODES_NICE if realtime and name != "twin_bridge" else 0,
        )
        for name in names
    ]
    env = {"PYTHONUNBUFFERED": "1", "RCUTILS_COLORIZED_OUTPUT": "0"}
    # DDS confined to loopback (+ the listed addresses in hardware mode): vigil/dds.py
    ros = dep.ros
    env.update(deployment_env(run_dir, ros.localhost_only, ros.interfaces, ros.peers))
    if dep.mode == "hardware" and dep.ros.keystore:
        env.update(security_env(dep.resolve(dep.ros.keystore)))
    if dep.ros.domain_id >= 0:
        env["ROS_DOMAIN_ID"] = str(dep.ros.domain_id)
    if dep.mode == "twin":
        env.setdefault("MUJOCO_GL", "egl")
    # one BLAS thread a node (unless the user set one): a dozen processes share the
    # cores, and the planner's small products only lose by more (stack.planning.threads)
    env.update({k: "1" for k in BLAS_THREAD_VARS if k not in os.environ})
    return System(run_dir, specs, {n: params[n] for n in names}, env, max_steps)


def host_specs(system: System, dep: Deployment, host: str | None) -> list[ProcessSpec]:
    """The processes ``host`` runs (the deployment's ``hosts``); all of them for None.

    Raises:
        ConfigError: an unknown host, a host listing a node the system does not have, or
            a node of the system on no host (it would run nowhere: e.g. the velocity
            gate of ``twin.velocity_gate`` left out).
    """
    if host is None:
        return list(system.specs)
    if host not in dep.hosts:
        raise ConfigError("--host", host, f"not a host of the deployment ({sorted(dep.hosts)})")
    names = {s.name for s in system.specs}
    for h, nodes in dep.hosts.items():
        unknown = sorted(set(nodes) - names)
        if unknown:
            raise ConfigError(f"hosts.{h}", unknown, f"not nodes of this system ({sorted(names)})")
    placed = {n for nodes in dep.hosts.values() for n in nodes}
    nowhere = sorted(names - placed)
    if nowhere:
        raise ConfigError("hosts", nowhere, "nodes of this system on no host: list each on one")
    return [s for s in system.specs if s.name in dep.hosts[host]]


GATE_HEARTBEAT_TIMEOUT_S = 0.25  # the twin's base with a gate: 5 of its 20 Hz beats missed


def realtime_twin(dep: Deployment) -> bool:
    """The deployment runs the twin on the wall clock (hardware in the loop)."""
    return dep.mode == "twin" and dep.twin.realtime and not dep.lockstep


def scene_people(
    scene: dict[str, Any], scenario: Scenario, grid: CellGrid, door_m: tuple[float, float]
) -> dict[str, Any]:
    """The twin scene's ``person`` (one walker) or ``people`` (several) for a scenario.

    Every walker takes the scene file's person section (``person``, or the first of
    ``people``) with its own waypoints; walkers after the first drop its clothes so
    that the twin dresses them apart (``twin.config.walker_config``).
    """
    listed = scene.pop("people", None)
    base = dict(scene.pop("person", None) or (listed[0] if listed else {}))
    base.pop("waypoints", None)
    walks = scenario.people_waypoints(grid, door_m)
    if len(walks) == 1:
        return {"person": {**base, "waypoints": walks[0]}}
    plain = {k: v for k, v in base.items() if k not in ("shirt_rgb", "trousers_rgb")}
    return {
        "people": [{**(base if i == 0 else plain), "waypoints": w} for i, w in enumerate(walks)]
    }


_CALIBRATIONS = Memo(8)  # twin config without walkers -> its calibration


def _calibrate_twin(twin_cfg, path: Path, say) -> None:
    """The camera's floor homography from points the twin reports (as on the robot,
    from measured floor points)."""
    from stack.perception.homography import save_calibration
    from twin.calibration import calibrate_twin
    from twin.config import PersonConfig
    from twin.twin import Twin

    # the walkers are all that changes between a study's episodes, and they never move
    # the camera: one calibration a process per room, camera and cells
    key = repr(replace(twin_cfg, person=PersonConfig(), people=()))

    def make():
        with Twin(twin_cfg, seed=0) as tw:
            return calibrate_twin(tw)

    cal = _CALIBRATIONS.get(key, make)
    save_calibration(path, cal)
    err_cm = cal.mean_error_m * 100
    say(f"[calibration] twin floor points: mean error {err_cm:.1f} cm -> {path.name}")
