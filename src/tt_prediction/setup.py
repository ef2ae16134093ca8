from glob import glob

from setuptools import find_packages, setup

package_name = 'tt_prediction'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
    ],
    install_requires=['setuptools', 'tt_ros'],
    zip_safe=True,
    maintainer='tt developers',
    maintainer_email='tt@example.org',
    description=(
        'Ball model of the tt stack: flight with drag and Magnus, table and racket '
        'rebounds, event-driven prediction of bounce, hit point and landing zone, and '
        'identification from measured data.'
    ),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'prediction_node = tt_prediction.node:main',
            'tt-predict = tt_prediction.cli:main',
            'tt-identify = tt_prediction.identify.cli:main',
        ],
    },
)
