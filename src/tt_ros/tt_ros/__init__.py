"""ROS glue shared by the tt nodes and tools (the only tt package besides the nodes' own
modules that imports rclpy): :mod:`tt_ros.executor` runs a node, :mod:`tt_ros.parameters`
declares, validates and applies its parameters, :mod:`tt_ros.messages` and
:mod:`tt_ros.markers` fill messages, :mod:`tt_ros.bagfile` reads and writes rosbag2 bags,
:mod:`tt_ros.connections` logs when a node's input gets or loses its publishers,
:mod:`tt_ros.shm` finds the Fast DDS shared memory a killed process left,
:mod:`tt_ros.worktime` times a callback over its latest calls; :mod:`tt_ros.errors` gives an
error's one-line reason and :mod:`tt_ros.yamlfile` reads tt's own YAML files (these two
without rclpy)."""
