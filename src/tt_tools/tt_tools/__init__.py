"""Tools of the tt stack: a ros2 command (run, topic, bag) for installs without ros2cli, bag
record and replay on rosbags, demo and synthetic recordings.
"""
