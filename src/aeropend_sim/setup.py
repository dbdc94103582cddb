"""ament_python build script for aeropend_sim."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "aeropend_sim"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={PACKAGE: ["rigs/*.yaml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
        ("share/" + PACKAGE + "/launch", glob("launch/*.py")),
        ("share/" + PACKAGE + "/config", glob("config/*.yaml")),
        ("share/" + PACKAGE + "/rigs", glob(PACKAGE + "/rigs/*.yaml")),
        ("share/" + PACKAGE + "/urdf", glob("urdf/*.urdf")),
        ("share/" + PACKAGE + "/rviz", glob("rviz/*.rviz")),
    ],
    install_requires=["setuptools"],
    extras_require={"test": ["pytest"]},
    zip_safe=True,
    maintainer="aeropend maintainers",
    maintainer_email="maintainers@aeropend.invalid",
    description=(
        "Aeropendulum plant model library (thesis Eqs. 3.1-3.10), rig parameter files, "
        "topic contract, simulated plant node and excitation node."
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            'sim_node = aeropend_sim.ros.sim_node:main',
            'excitation = aeropend_sim.ros.excitation_node:main'
        ],
    },
)
