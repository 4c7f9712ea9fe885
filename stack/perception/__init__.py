"""Perception: the camera's person position and direction, the laser's speed (thesis 4.5).

A pure library (numpy, OpenCV, PyYAML; never rclpy) with thin ROS nodes in
``node_*.py``. See docs/PERCEPTION.md.

- :mod:`.hog`: HOG people detection and the foot point (figure 4.9);
- :mod:`.homography`: image-to-floor homography (eqs. 4.4-4.7) and calibration files;
- :mod:`.direction`: movement direction from map positions;
- :mod:`.camera`: frames -> person cell and direction, two-missed-frames rule;
- :mod:`.legs`: leg detection in laser scans;
- :mod:`.tracker`: constant-velocity Kalman tracks, speed (eq. 4.8);
- :mod:`.observation`: the planner's observation per decision step;
- :mod:`.messages`: ROS message conversions (no rclpy import);
- :mod:`.synthetic`: synthetic frames and scans with ground truth, for tests and benchmarks.
"""
