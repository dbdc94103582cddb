"""ament_python build script for aeropend_control."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "aeropend_control"

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
        "Aeropendulum controllers: PID, small-signal linearisation, feedback "
        "linearisation, cascade (thesis chapter 6)."
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "design_gains = aeropend_control.design_gains:main",
            "controller = aeropend_control.controller_node:main",
        ],
    },
)
