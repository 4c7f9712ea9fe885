"""Navigation and speech: occupancy maps, A*, cell waypoints, holonomic path following,
espeak-ng warnings (pure modules), and the ``node_navigation`` / ``node_speech`` ROS 2
nodes. See docs/NAV.md."""
