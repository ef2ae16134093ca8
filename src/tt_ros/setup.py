from setuptools import find_packages, setup

package_name = 'tt_ros'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='tt developers',
    maintainer_email='tt@example.org',
    description=(
        'ROS glue shared by the tt nodes and tools: running a node, declarative parameters, '
        'message and marker helpers, rosbag2 files on rosbags.'
    ),
    license='Apache-2.0',
)
