"""Every ROS topic name the stack uses, defined once (docs/INTERFACES.md lists types).

Nodes take these as the defaults of their ``*_topic`` parameters, so a deployment can
remap any of them; tests and the launcher read them from here too.
"""

from __future__ import annotations

# sensors and the base
CLOCK = "/clock"
ODOM = "/odom"
AMCL_POSE = "/amcl_pose"
SCAN = "/scan"
MAP = "/map"
CAMERA_IMAGE = "/camera/image_raw"
CAMERA_INFO = "/camera/camera_info"
DIAGNOSTICS = "/diagnostics"  # diagnostic_msgs/DiagnosticArray: camera_stream, velocity_gate
CMD_VEL = "/cmd_vel"  # the base's command (hardware: only the velocity gate publishes it)
NAV_CMD_VEL = "/nav/cmd_vel"  # navigation's command into the velocity gate (hardware)
ARM = "/arm"
# std_msgs/UInt64, a count: the velocity gate is alive (its timer ran), at rate_hz whatever
# its state, so a base-side watchdog can tell a dead gate from a quiet one
GATE_HEARTBEAT = "/velocity_gate/heartbeat"
# the gate's parameter services (rcl_interfaces): `vigil arm`, `vigil disarm` and `vigil
# status` set and read its ``armed`` parameter there (the node is named velocity_gate)
GATE_SET_PARAMETERS = "/velocity_gate/set_parameters"
GATE_GET_PARAMETERS = "/velocity_gate/get_parameters"
STOP = "/stop"
GOAL_POSE = "/goal_pose"
TF = "/tf"  # tf2_msgs/TFMessage: odom -> base_link (bridge), map -> odom (localisation)
TF_STATIC = "/tf_static"  # base_link -> laser (bridge), map -> camera_link -> optical

# perception
PERSON = "/perception/person"
PERSON_POSITION = "/perception/person_position"
PERSON_CELL = "/perception/person_cell"
PERSON_DIRECTION = "/perception/person_direction"
LEGS = "/perception/legs"
LEG_PEOPLE = "/perception/leg_people"
OBSERVATIONS = "/observations"
OBSERVATIONS_REQUEST = "/observations/request"

# navigation, speech, planner
NAV_ACTION = "/nav/action"
NAV_ACTION_ID = "/nav/action_id"
NAV_PROGRESS = "/nav/progress"
NAV_RESULT = "/nav/result"
NAVIGATE_TO_POSE = "navigate_to_pose"  # the NavigateToPose action (nav2's name), navigation
SPEECH_SAY = "/speech/say"
SPEECH_DONE = "/speech/done"
SPEECH_SPEAKING = "/speech/speaking"
SPEECH_WARNING = "/speech/warning"
PLANNER_BELIEF = "/planner/belief"
MARKERS = "/vigil/markers"  # visualization_msgs/MarkerArray (vigil/node_markers.py)
PLANNER_STEP = "/planner/step"
PLANNER_DONE = "/planner/done"

# the twin's ground truth and lock-step
TWIN_TRUTH = "/twin/truth"
TWIN_ROBOT_POSE = "/twin/robot_pose"
TWIN_ROBOT_CELL = "/twin/robot_cell"
TWIN_PERSON_POSE = "/twin/person_pose"
TWIN_PERSON_CELL = "/twin/person_cell"
TWIN_PERSON_VELOCITY = "/twin/person_velocity"
LOCKSTEP_ACK = "/lockstep/ack"
LOCKSTEP_TICK = "/lockstep/tick"  # after /clock has reached everyone: run the timers
