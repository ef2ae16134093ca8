"""Build of the ROS 2 (ament_python) package; its metadata is declared in setup.cfg."""

from setuptools import setup

setup()
