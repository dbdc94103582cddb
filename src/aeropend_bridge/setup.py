"""ament_python build script for aeropend_bridge."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "aeropend_bridge"

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
    ],
    install_requires=["setuptools"],
    extras_require={"test": ["pytest"]},
    zip_safe=True,
    maintainer="aeropend maintainers",
    maintainer_email="maintainers@aeropend.invalid",
    description=(
        "Serial bridge to the Arduino Mega acquisition firmware; publishes the same "
        "topics as the simulated plant."
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "bridge = aeropend_bridge.bridge_node:main",
            "fake_mcu = aeropend_bridge.fake_mcu:main",
            "bridge_check = aeropend_bridge.bridge_check_node:main",
        ],
    },
)
