from setuptools import find_packages, setup

PACKAGE = "msfsu_common"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={PACKAGE: ["fastdds_profile.xml"]},  # msfsu_common.transport.FASTDDS_PROFILE
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ],
    zip_safe=False,
    maintainer="MSFSU team",
    maintainer_email="msfsu@example.com",
    description="Shared ROS-side helpers of the MSFSU stack: ROS environment, road options, topic names, image conversion.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
        ],
    },
)
