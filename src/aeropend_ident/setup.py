"""ament_python build script for aeropend_ident."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "aeropend_ident"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={PACKAGE: ["io/presets/*.yaml"]},
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
        "Offline identification and sim-to-real gap diagnosis on rosbag2 files (rosbags, "
        "no ROS install needed); recorder, player and CSV import."
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            'record = aeropend_ident.nodes.record:main',
            'play = aeropend_ident.nodes.play:main',
            'topics = aeropend_ident.nodes.topics:main',
            'csv_import = aeropend_ident.cli.csv_import:main',
            'baseline = aeropend_ident.cli.baseline:main',
            'pipeline = aeropend_ident.cli.pipeline:main',
            'identify = aeropend_ident.cli.identify:main',
            'gap = aeropend_ident.cli.gap:main',
            'gap-batch = aeropend_ident.cli.gap_batch:main',
            'compare = aeropend_ident.cli.compare:main',
            'excitation_design = aeropend_ident.design.cli:main',
            'reindex = aeropend_ident.cli.reindex:main',
            'rig = aeropend_ident.cli.rig:main'
        ],
    },
)
