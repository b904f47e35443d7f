"""The robot case study: multi-robot Escape Room with TurtleBot3-sized robots in MuJoCo.

Modules: `world` (the MJCF of room, zones, gate and robots), `controller`
(go-to-goal and wheel mapping), `messages` (Twist/Odometry-shaped topics),
`episode` (the decision loop and the ER rules on zones), `evaluate` (trained
runs in physics next to the abstract env), `rosbag` (ROS 2 bags, MCAP or sqlite3,
Humble or Jazzy types), `ros_wire` (ROS 2 messages on DDS through cyclonedds),
`serve` (`pimbot robot serve`: the controller on the ROS 2 wire), `ros_world`
(`pimbot robot world`: the MuJoCo robots on the same topics), `export`,
`exportable`, `export_check` (`pimbot export`: policies as ONNX, checked against
pimbot's actor), `render` (MuJoCo offscreen or matplotlib videos), `gl` (OpenGL
backend choice). Importing this package does not import mujoco.
"""
