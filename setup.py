from glob import glob

from setuptools import find_packages, setup

package_name = 'thermal_imu_calib'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*', 'bench', 'scripts']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
    ],
    install_requires=[
        'setuptools',
        'numpy>=1.24',
        'scipy>=1.10',
        'PyYAML>=6',
        'rosbags>=0.10',
        'mcap>=1.1',
        'mcap-ros2-support>=0.5',
        'tqdm>=4.60',
        'scikit-learn>=1.3',
        'matplotlib>=3.7',
        'allantools>=2019.9',
        'dask[distributed]>=2024.1',
        'threadpoolctl>=3',
        'zlib-ng>=0.5',
    ],
    extras_require={
        'test': ['pytest>=7', 'pytest-xdist>=3.5', 'flake8>=6', 'pydocstyle>=6',
                 'hypothesis>=6.80'],
    },
    zip_safe=True,
    maintainer='thermal_imu_calib maintainers',
    maintainer_email='maintainers@thermal-imu-calib.invalid',
    description='Temperature compensation and field thermal calibration of IMUs (ROS 2 Jazzy).',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'thermal-imu-calib = thermal_imu_calib.cli.entry:main',
            'compensator_node = thermal_imu_calib.nodes.compensator:main',
            'calibrator_node = thermal_imu_calib.nodes.calibrator:main',
            'bringup = thermal_imu_calib.nodes.bringup:main',
        ],
    },
)
