from setuptools import find_packages, setup

package_name = 'eha_health'

# src layout for the library; msg_bridge sits at the repository root.  Each
# top-level package under src/ is mapped explicitly (rather than with a
# '' -> 'src' default) so that `colcon build --symlink-install` works too:
# colcon refuses a package_dir mapping like 'msg_bridge' -> 'msg_bridge'.
src_packages = find_packages('src')
package_dir = {p: 'src/' + p for p in src_packages if '.' not in p}

setup(
    name=package_name,
    version='0.1.0',
    description='ROS 2 health monitor for aircraft electrohydraulic servo actuators',
    maintainer='eha_health developers',
    maintainer_email='eha-health@example.org',
    license='Apache-2.0',
    package_dir=package_dir,
    packages=src_packages + ['msg_bridge'],
    package_data={package_name: ['data/*.yaml', 'data/*.json']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    python_requires='>=3.10',
    install_requires=[
        'numpy>=1.26',
        'scipy>=1.11',
        'numba>=0.60',
        'pymoo>=0.6',
        'pyyaml>=6.0',
        'matplotlib>=3.8',
        'mcap>=1.6',
        'mcap-ros2-support>=0.6',
        'dask[distributed]>=2024.8',
    ],
    extras_require={
        # ROS 2 Jazzy from PyPI wheels (a venv is required: the wheels'
        # bootstrapper re-execs Python with LD_LIBRARY_PATH set).
        'ros': [
            'ros-jazzy-rclpy[fastrtps]==7.1.6',
            'ros-jazzy-rmw-fastrtps-cpp==8.4.3',
            'ros-jazzy-common-interfaces==5.3.6',
            'ros-jazzy-std-srvs==5.3.6',
        ],
        'test': ['pytest', 'rosbags', 'filterpy', 'hypothesis'],
    },
    entry_points={
        'console_scripts': [
            'eha-health = eha_health.cli:main',
            'eha-plant = eha_health.ros.plant:main',
            'eha-command = eha_health.ros.command:main',
            'eha-monitor = eha_health.ros.monitor:main',
            'eha-replay = eha_health.ros.replay:main',
        ],
    },
    zip_safe=True,
)
