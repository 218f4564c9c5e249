import ast
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

package_name = 'cobot_calib_ros'


def node_registry() -> tuple[str, ...]:
    """cobot_calib_ros.nodes.NODES, the one node list, read without importing the package."""
    tree = ast.parse((Path(__file__).parent / package_name / 'nodes' / '__init__.py').read_text())
    return next(ast.literal_eval(node.value) for node in tree.body if isinstance(node, ast.Assign)
                and [t.id for t in node.targets if isinstance(t, ast.Name)] == ['NODES'])


NODES = node_registry()
# rosbag2 record / play on rclpy (cobot_calib_ros.bags): `ros2 run cobot_calib_ros bag_player`
BAG_NODES = ['bag_player', 'bag_recorder']

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    # the results database's alembic migrations (store.database): not a package, data
    package_data={package_name + '.store': ['migrations/*.py', 'migrations/*.mako',
                                            'migrations/versions/*.py']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml') + glob('config/*.xml')),
        ('share/' + package_name + '/config/cells', glob('config/cells/*.yaml')
         + glob('config/cells/*.urdf') + glob('config/cells/*.LICENSE')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='cobot_calib_ros maintainers',
    maintainer_email='maintainers@cobot-calib.example.com',
    description='Live calibration of a collaborative-robot cell on ROS 2.',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={'console_scripts': [
        *[f'{node} = cobot_calib_ros.nodes.{node}:main' for node in NODES],
        *[f'{node} = cobot_calib_ros.bags.{node.removeprefix("bag_")}:main'
          for node in BAG_NODES],
        'cobot-calib = cobot_calib_ros.cli.main:main',
    ]},
)
