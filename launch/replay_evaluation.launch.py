"""Replay a bag through the greybox and NARX predictors and the evaluator (full ROS 2 installs).

    ros2 launch quad_modelling replay_evaluation.launch.py bag:=/path/to/bag narx_model:=/path/narx.npz

The same graph as ``quad-modelling run-bag`` (which needs no launch system).
Node parameters come from config/*.yaml; the arguments below override them.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

PACKAGE = "quad_modelling"


def generate_launch_description():
    config = PathJoinSubstitution([FindPackageShare(PACKAGE), "config"])
    # Reliable subscriptions: the replay is paced on the evaluator's acknowledgements and loses nothing.
    # The vehicle is the bag's: the replay announces it on topic vehicle, the other nodes learn it.
    common = {"window_s": LaunchConfiguration("window_s"), "qos": "replay"}
    return LaunchDescription([
        DeclareLaunchArgument("bag", description="MCAP bag directory to replay"),
        DeclareLaunchArgument("narx_model", description="NARX model file (.npz, from quad-modelling train); required"),
        DeclareLaunchArgument("rate", default_value="0.0", description="real-time factor; 0 = as fast as acknowledged"),
        DeclareLaunchArgument("window_s", default_value="10.0", description="window length [s]"),
        DeclareLaunchArgument("output_dir", default_value="", description="where the evaluator writes results.json"),
        Node(package=PACKAGE, executable="evaluator", name="evaluator", namespace="quad", output="screen",
             parameters=[PathJoinSubstitution([config, "evaluator.yaml"]), common,
                         {"models": ["greybox", "narx"], "output_dir": LaunchConfiguration("output_dir")}]),
        Node(package=PACKAGE, executable="greybox_predictor", name="greybox_predictor", namespace="quad", output="screen",
             parameters=[PathJoinSubstitution([config, "greybox_predictor.yaml"]), common]),
        Node(package=PACKAGE, executable="narx_predictor", name="narx_predictor", namespace="quad", output="screen",
             parameters=[PathJoinSubstitution([config, "narx_predictor.yaml"]), common,
                         {"model_file": LaunchConfiguration("narx_model")}]),
        Node(package=PACKAGE, executable="replay", name="replay", namespace="quad", output="screen",
             parameters=[PathJoinSubstitution([config, "replay.yaml"]),
                         {"bag": LaunchConfiguration("bag"), "rate": LaunchConfiguration("rate"), "wait_for_subscribers": 3}]),
    ])
