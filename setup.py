"""reachset_ros: ament_python package (colcon on Jazzy) and pip-installable (make test/demo)."""
from glob import glob

from setuptools import Extension, find_packages, setup

PACKAGE = "reachset_ros"

NODES = {
    "plant_input_talker": "reachset_ros.nodes.talker:main",
    "sim_node": "reachset_ros.nodes.sim_node:main",
    "reference_node": "reachset_ros.nodes.reference_node:main",
    "observer_node": "reachset_ros.nodes.observer_node:main",
    "controller_node": "reachset_ros.nodes.controller_node:main",
    "monitor_node": "reachset_ros.nodes.monitor_node:main",
    "controller_lifecycle_node": "reachset_ros.nodes.controller_lifecycle_node:main",
    "monitor_lifecycle_node": "reachset_ros.nodes.monitor_lifecycle_node:main",
    "recorder_node": "reachset_ros.nodes.recorder_node:main",
    "synthesis_node": "reachset_ros.nodes.synthesis_node:main",
    "relay_node": "reachset_ros.nodes.relay_node:main",
}
# The online monitor's tick (reachset_ros/conformance/kernels.py loads it with ctypes; numpy is the
# fallback). No fused multiply-add: its results must equal numpy's bit for bit.
TICK_KERNEL = Extension(f"{PACKAGE}.conformance._tick", [f"{PACKAGE}/conformance/_tick.c"],
                        extra_compile_args=["-std=c99", "-O3", "-ffp-contract=off", "-fno-fast-math"])

SCRIPTS = ["reachset = reachset_ros.cli:main"] + [f"{k} = {v}" for k, v in NODES.items()]


setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    package_data={PACKAGE: ["data/*", "data/**/*"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
        ("share/" + PACKAGE + "/config", glob("config/*")),
        ("share/" + PACKAGE + "/launch", glob("launch/*.launch.py")),
    ],
    ext_modules=[TICK_KERNEL],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="reachset_ros developers",
    maintainer_email="dev@reachset-ros.invalid",
    description="Reachset-conformant identification, controller synthesis and online monitoring (ROS 2 Jazzy).",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={"console_scripts": SCRIPTS},
)
