from setuptools import setup

# Metadata in setup.cfg; here what this package needs (the tt ones as in package.xml).
setup(install_requires=['setuptools', 'tt_perception', 'tt_prediction', 'tt_strike', 'tt_ros'])
