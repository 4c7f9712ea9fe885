"""The planner node: observations in, actions out, one decision step at a time (4.3).

Each step: choose an action from the belief, publish it, wait until navigation reports
the action done (a move: the robot entered its target cell; anything else: and at least
``min_step_s``), ask for the step's observations, update
the belief, record the step (section 4.3). A step also ends early, at least
``min_event_step_s`` after it began, when the observations show the person in a cell
other than at the last step (entering the room, a restricted cell, any new cell):
the robot reacts to a walker instead of finishing a move first. Navigation keeps
driving meanwhile; a next action toward the same cell does not stop it.

Subscribes (names are parameters):
    ``/nav/result`` vigil_interfaces/NavResult: navigation's result, matched to the
        step's goal by ``goal_id`` (a late result of an earlier goal is ignored).
    ``/observations`` vigil_interfaces/PersonObservation: the observations node's
        labels {"robot": "7", "person": "9", "velocity": "East higher", ...}.

Publishes:
    ``/nav/action`` vigil_interfaces/NavGoal: the action ("North", "South", "East",
        "West", "Do nothing") with its goal id (the step's number).
    ``/observations/request`` std_msgs/Empty: asks for the step's observations.
    ``/planner/belief`` vigil_interfaces/Belief: the marginals after every update.
    ``/planner/step`` vigil_interfaces/Decision: each step's record (as ``steps_file``).
    ``/planner/done`` vigil_interfaces/PlannerDone: when ``max_steps`` are done.

Parameters: ``task_file``, ``policy_file`` (alpha vectors, ``vigil solve``),
``state_file`` (belief and step, written after every change; an existing one is
resumed: a node restarted within a run continues; ``vigil launch`` puts an earlier
launch's state there only with ``--resume``, :func:`vigil.launch.resume_decision`),
``steps_file`` (JSON lines, appended), ``initial_robot_cell`` (0: the
task's), ``initial_person_cell`` (-1: the task's, 0: nobody), ``initial_direction``
("": the task's), ``max_steps`` (0: no end), ``start_delay_s``, ``nav_timeout_s``,
``obs_timeout_s``, ``resume_wait_s``, ``online_depth``, ``online_samples``,
``online_time_limit_s`` (a task with two or more people: the online planner's search,
:mod:`stack.planning.online`; no policy file then; 0: no time limit, so that a run is
repeatable), ``min_step_s`` (a step lasts at least this long: "Do
nothing" is done at once, but the model's time steps are of one length, about one
cell's move), ``min_event_step_s`` (a step ends on a person event no sooner; 0: no
events), ``lockstep`` (see :mod:`stack.ros_lockstep`).
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

from rclpy.node import Node
from std_msgs.msg import Empty
from vigil_interfaces.msg import (
    Belief,
    Decision,
    NavGoal,
    NavResult,
    PersonObservation,
    PlannerDone,
)

import stack.topics as topic
from stack.config import open_write
from stack.planning.agent import ObservationError, Observed, PlannerAgent, StateFileError
from stack.planning.people_agent import PeopleAgent
from stack.planning.runtime import ONLINE_DEFAULTS, PlannerStart, make_planner, online_config
from stack.planning.stepper import Command, DecisionSteps, StepTiming
from stack.ros_lockstep import Participant
from stack.ros_main import spin_node
from stack.ros_msgs import (
    belief_to_msg,
    decision_to_msg,
    nav_goal_to_msg,
    nav_result_from_msg,
    observation_from_msg,
    planner_done_to_msg,
)
from stack.ros_params import declare


class PlannerNode(Node):
    """Holds the policy and the belief; publishes what the step machine decides."""

    def __init__(self, **kwargs):
        super().__init__("planner", **kwargs)
        v = declare(
            self,
            task_file="",
            policy_file="",
            state_file="",
            steps_file="",
            initial_robot_cell=0,
            initial_person_cell=-1,
            initial_direction="",
            lockstep=False,
        )
        task_file, policy_file = v.task_file, v.policy_file
        self.state_file, self.steps_file = v.state_file, v.steps_file
        robot, person = v.initial_robot_cell, v.initial_person_cell
        direction = v.initial_direction
        # one parameter per field, defaulting to the field's default
        timing = StepTiming(**vars(declare(self, **dataclasses.asdict(StepTiming()))))
        online = online_config(vars(declare(self, **ONLINE_DEFAULTS)))
        setup = make_planner(task_file, policy_file, PlannerStart(robot, person, direction), online)
        self.agent: PlannerAgent | PeopleAgent = setup.agent
        first_person, what_policy = setup.first_person, setup.description
        resumed = False
        if self.state_file:
            try:
                resumed = self.agent.restore(self.state_file)
            except StateFileError as err:
                bad = self.state_file + ".bad"
                os.replace(self.state_file, bad)
                self.get_logger().error(f"{err}; kept as {bad}, starting from the initial belief")
        ls = self.lockstep = Participant(self, v.lockstep)
        # the start delay counts from now: a simulated clock starts at 0 with the run, a
        # real one is an epoch time
        origin = 0.0 if ls.enabled else self.now_s()
        self.steps = DecisionSteps(self.agent, timing, first_person, resumed, origin_s=origin)
        self.pub_action = ls.publisher(NavGoal, topic.NAV_ACTION, 10)
        self.pub_request = ls.publisher(Empty, topic.OBSERVATIONS_REQUEST, 10)
        self.pub_belief = ls.publisher(Belief, topic.PLANNER_BELIEF, 10)
        self.pub_step = ls.publisher(Decision, topic.PLANNER_STEP, 10)
        self.pub_done = ls.publisher(PlannerDone, topic.PLANNER_DONE, 10)
        ls.subscription(NavResult, topic.NAV_RESULT, self.on_result, 10)
        ls.subscription(PersonObservation, topic.OBSERVATIONS, self.on_observation, 10)
        ls.timer(0.1, self.poll)
        what = f"resuming at step {self.agent.step + 1}" if resumed else "initial belief"
        self.get_logger().info(f"planner: {Path(task_file).name}, {what_policy}, {what}")

    def now_s(self) -> float:
        return self.lockstep.now_s()

    # -- inputs --------------------------------------------------------------------------
    def poll(self) -> None:
        self.run(self.steps.tick(self.now_s()))

    def on_result(self, msg: NavResult) -> None:
        try:
            body = nav_result_from_msg(msg)
        except ValueError as err:
            self.get_logger().warning(f"malformed navigation result ignored: {err}")
            return
        self.run(self.steps.on_nav_result(self.now_s(), body))

    def on_observation(self, msg: PersonObservation) -> None:
        if self.steps.waiting not in ("obs", "nav", "hold"):
            return
        try:
            observed = Observed.from_dict(observation_from_msg(msg))
            commands = self.steps.on_observation(self.now_s(), observed)
        except (ValueError, ObservationError) as err:
            self.get_logger().error(f"observation ignored: {err}", throttle_duration_sec=5.0)
            return
        self.run(commands)

    # -- outputs -------------------------------------------------------------------------
    def run(self, commands: list[Command]) -> None:
        for c in commands:
            if c.kind == "act":
                self.save()
                self.pub_action.publish(nav_goal_to_msg(c.goal_id, c.action, self.now_s()))
                self.get_logger().info(f"step {self.agent.step + 1}: {c.action} (goal {c.goal_id})")
            elif c.kind == "request":
                self.pub_request.publish(Empty())
            elif c.kind == "record" and c.record is not None:
                self.save()
                self.write_record(c.record)
                r = c.record
                self.pub_belief.publish(belief_to_msg(r["belief"], r["step"], self.now_s()))
                self.pub_step.publish(decision_to_msg(r))
                o = c.record["observation"]
                self.get_logger().info(
                    f"step {c.record['step']}: {c.record['action']} -> robot {o['robot']}, "
                    f"person {o['person']}, {o['velocity']}"
                )
            elif c.kind == "done":
                self.save()
                self.pub_done.publish(planner_done_to_msg(self.agent.step, self.now_s()))
                self.get_logger().info(f"done after {self.agent.step} steps")
            elif c.kind == "log":
                self.get_logger().warning(c.text)

    # -- files --------------------------------------------------------------------------
    def save(self) -> None:
        if self.state_file:
            self.agent.save(self.state_file)

    def write_record(self, record: dict) -> None:
        if not self.steps_file:
            return
        with open_write(self.steps_file, "a") as f:
            f.write(json.dumps(record, sort_keys=True) + "\n")
            f.flush()
            os.fsync(f.fileno())


def main(args=None) -> None:
    spin_node(PlannerNode, args)


if __name__ == "__main__":
    main()
