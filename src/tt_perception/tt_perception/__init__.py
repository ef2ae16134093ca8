"""Perception of the tt stack: capture from V4L2 cameras, image topics or video files, ball
detection, triangulation and state estimation.
"""
