"""`colcon build` of ros2_ws against the pip-installed ROS 2 (what a ROS user runs)."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = sorted(p.name for p in (REPO / "ros2_ws" / "src").iterdir())


def test_colcon_builds_every_package_of_the_workspace(tmp_path):
    venv = Path(sys.prefix)
    env = dict(os.environ, AMENT_PREFIX_PATH=str(venv), CMAKE_PREFIX_PATH=str(venv))
    colcon = shutil.which("colcon", path=str(venv / "bin"))
    assert colcon, "colcon is installed by the setup"
    result = subprocess.run(
        [colcon, "--log-base", str(tmp_path / "log"), "build", "--base-paths", str(REPO / "ros2_ws" / "src"),
         "--build-base", str(tmp_path / "build"), "--install-base", str(tmp_path / "install"),
         "--event-handlers", "console_direct-", "--cmake-args", "-DBUILD_TESTING=OFF", f"-DPython3_EXECUTABLE={sys.executable}"],
        env=env, capture_output=True, text=True, timeout=600,
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    install = tmp_path / "install"
    assert sorted(p.name for p in install.iterdir() if p.is_dir()) == PACKAGES
    for package, executable in [("msfsu_perception", "perception"), ("msfsu_control", "control"),
                                ("msfsu_control", "route"), ("msfsu_bringup", "bag_player"),
                                ("msfsu_bringup", "bag_recorder"), ("msfsu_evaluation", "msfsu-eval-bag")]:
        assert (install / package / "lib" / package / executable).is_file(), f"{package}/{executable}"
    assert list((install / "msfsu_interfaces").rglob("msfsu_interfaces/msg/_driving_action.py"))
    assert list((install / "carla_msgs").rglob("carla_msgs/msg/_carla_ego_vehicle_control.py"))
    assert (install / "msfsu_bringup" / "share" / "msfsu_bringup" / "profiles" / "replay.yaml").is_file()
    launch_files = sorted(p.name for p in (install / "msfsu_bringup" / "share" / "msfsu_bringup" / "launch").iterdir())
    assert launch_files == sorted(p.name for p in (REPO / "msfsu_bringup" / "launch").glob("*.launch.py"))
