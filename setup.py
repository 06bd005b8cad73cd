"""ament_python package tak_thermo_ros."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'tak_thermo_ros'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(include=[PACKAGE, f'{PACKAGE}.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', [f'resource/{PACKAGE}']),
        (f'share/{PACKAGE}', ['package.xml']),
        (f'share/{PACKAGE}/config', glob('config/*.yaml')),
        (f'share/{PACKAGE}/launch', glob('launch/*.launch.py')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='tak_thermo_ros developers',
    maintainer_email='dev@tak-thermo-ros.invalid',
    description=('Temperature-drift compensation of an IMU (accelerometer and gyroscope; driver Imu or raw codes): '
                 'the compensator node, and tak_calib to fit, validate and discover the model from rosbags.'),
    license='Apache-2.0',
    python_requires='>=3.11',
    entry_points={
        'console_scripts': [
            f'tak_calib = {PACKAGE}.cli:main',
            f'compensator = {PACKAGE}.ros.main:main',
        ],
    },
)
