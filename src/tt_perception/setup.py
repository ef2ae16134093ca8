from glob import glob

from setuptools import find_packages, setup

package_name = 'tt_perception'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
    ],
    install_requires=['setuptools', 'tt_prediction', 'tt_ros'],
    zip_safe=True,
    maintainer='tt developers',
    maintainer_email='tt@example.org',
    description=(
        'Perception of the tt stack: capture from V4L2 cameras, image topics or video '
        'files, ball detection, triangulation and state estimation.'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'perception_node = tt_perception.node:main',
            'tt-perceive = tt_perception.cli:main',
        ],
    },
)
