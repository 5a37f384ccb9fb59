from setuptools import find_packages, setup

PACKAGE = "msfsu_control"

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
    description="Longitudinal PID control node, route (navigation command) node and emergency brake (aeb) node.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "aeb = msfsu_control.aeb_node:main",
            "aeb_control = msfsu_control.aeb_control:main",
            "control = msfsu_control.control_node:main",
            "route = msfsu_control.route_node:main",
        ],
    },
)
