from glob import glob

from setuptools import find_packages, setup

package_name = 'tt_tools'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml') + glob('config/*.xml')),
    ],
    install_requires=['setuptools', 'tt_perception', 'tt_prediction', 'tt_strike', 'tt_ros'],
    zip_safe=True,
    maintainer='tt developers',
    maintainer_email='tt@example.org',
    description=(
        'Tools of the tt stack: a ros2 command (run, topic, bag) for installs without '
        'ros2cli, bag record and replay on rosbags, demo and synthetic recordings.'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'ros2 = tt_tools.ros2:main',
            'bringup = tt_tools.bringup:main',
        ],
    },
)
