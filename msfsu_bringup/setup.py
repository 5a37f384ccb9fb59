from glob import glob

from setuptools import find_packages, setup

PACKAGE = "msfsu_bringup"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/profiles", glob(f"{PACKAGE}/profiles/*.yaml")),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
    ],
    package_data={PACKAGE: ["profiles/*.yaml", "product.yaml"]},
    zip_safe=False,
    maintainer="MSFSU team",
    maintainer_email="msfsu@example.com",
    description="Starts the MSFSU node graph from YAML profiles; rosbag2 MCAP player and recorder.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "bag_player = msfsu_bringup.bag_player:main",
            "bag_recorder = msfsu_bringup.bag_recorder:main",
            "msfsu-bringup = msfsu_bringup.launcher:main",
        ],
    },
)
