from glob import glob

from setuptools import find_packages, setup

package_name = 'tt_strike'

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
        'Strike solver of the tt stack: racket velocity and orientation that send the '
        'ball to a target zone.'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'strike_node = tt_strike.node:main',
            'tt-strike = tt_strike.cli:main',
        ],
    },
)
