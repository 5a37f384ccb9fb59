from setuptools import find_packages, setup

PACKAGE = "msfsu_sim"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={PACKAGE: ["shaders/*.glsl"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ],
    zip_safe=False,
    maintainer="MSFSU team",
    maintainer_email="msfsu@example.com",
    description="Embedded MetaDrive simulator: offline assets, llvmpipe rendering, expert and on-policy (DAgger) data collection to MCAP, live bridge node.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "msfsu-sim-assets = msfsu_sim.assets:main",
            "msfsu-collect = msfsu_sim.collect:main",
            "msfsu-import-carla = msfsu_sim.carla.importer:main",
            "sim_bridge = msfsu_sim.bridge_node:main",
        ],
    },
)
