from setuptools import find_packages, setup

PACKAGE = "msfsu_perception"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ],
    zip_safe=False,
    maintainer="MSFSU team",
    maintainer_email="msfsu@example.com",
    description="MSFSU network, preprocessing, training and the perception node.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "perception = msfsu_perception.perception_node:main",
            "msfsu-train = msfsu_perception.train:main",
            "msfsu-export-onnx = msfsu_perception.export:main",
            "msfsu-calibrate = msfsu_perception.calibration:main",
            "msfsu-release-checkpoint = msfsu_perception.checkpoint:main",
        ],
    },
)
