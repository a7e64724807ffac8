from glob import glob

from setuptools import find_packages, setup

package_name = 'ros_ehs'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*', 'bags', 'launch_scripts']),
    # the station's page and its vendored scripts (rig networks are offline: no CDN)
    package_data={'ros_ehs.web': ['static/*.*', 'static/vendor/*'],
                  'ros_ehs.nodes': ['fastdds.xml']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/launch_scripts',
         glob('launch_scripts/*.py') + glob('launch_scripts/*.xml')),
    ],
    install_requires=['setuptools', 'numpy', 'scipy', 'numba', 'pyyaml', 'matplotlib', 'psutil',
                      'mcap', 'mcap-ros2-support', 'aiohttp', 'rosbags', 'threadpoolctl',
                      'sqlalchemy', 'distributed'],
    extras_require={'test': ['pytest']},
    zip_safe=False,
    maintainer='ros_ehs maintainers',
    maintainer_email='maintainers@ros-ehs.dev',
    description='Electro-hydraulic servo axis: model, controller, identification, ROS 2 nodes',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'ehs_sim = ros_ehs.tools.cli:main',
            'plant = ros_ehs.nodes.plant:main',
            'controller = ros_ehs.nodes.controller:main',
            'reference = ros_ehs.nodes.reference:main',
            'recorder = ros_ehs.nodes.recorder:main',
            'player = ros_ehs.nodes.player:main',
            'identify = ros_ehs.nodes.identify:main',
            'procedure = ros_ehs.nodes.procedure:main',
            'station = ros_ehs.nodes.station:main',
            'campaign = ros_ehs.nodes.campaign:main',
        ],
    },
)
