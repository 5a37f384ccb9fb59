"""An environment like a sourced colcon install with ros2cli, for tests of what runs where ros2cli is installed (the
Docker image): the stack's packages in an ament index, and a `ros2` on PATH that behaves like Jazzy's `ros2 run`."""

from __future__ import annotations

import os
import sys
from pathlib import Path

# Jazzy's `ros2 run` (ros2run.api.run_executable): the node runs as its child; SIGINT is swallowed (a terminal sends
# it to the node too), nothing is forwarded, SIGTERM ends the wrapper alone.
JAZZY_ROS2_RUN = """#!{python}
import os, subprocess, sys
from pathlib import Path
verb, package, executable, *argv = sys.argv[1:]
assert verb == "run", verb
prefix = next(p for p in os.environ["AMENT_PREFIX_PATH"].split(os.pathsep)
              if (Path(p) / "share/ament_index/resource_index/packages" / package).is_file())
process = subprocess.Popen([str(Path(prefix) / "lib" / package / executable), *argv])
while process.returncode is None:
    try:
        process.communicate()
    except KeyboardInterrupt:
        pass
sys.exit(process.returncode)
"""


def ros2cli_environment(root: Path, package: str, executables: list[str]) -> dict[str, str]:
    """An environment like a sourced colcon install with ros2cli: `package` in an ament index under `root`, its
    executables in lib/<package>/ (the venv's console scripts), and a `ros2` on PATH that behaves like Jazzy's."""
    prefix, bin_dir = root / "install", root / "bin"
    marker = prefix / "share" / "ament_index" / "resource_index" / "packages" / package
    marker.parent.mkdir(parents=True)
    marker.touch()
    (prefix / "lib" / package).mkdir(parents=True)
    for executable in executables:
        (prefix / "lib" / package / executable).symlink_to(Path(sys.executable).parent / executable)
    bin_dir.mkdir()
    (bin_dir / "ros2").write_text(JAZZY_ROS2_RUN.format(python=sys.executable))
    (bin_dir / "ros2").chmod(0o755)
    return dict(os.environ, PATH=f"{bin_dir}{os.pathsep}{os.environ['PATH']}", AMENT_PREFIX_PATH=str(prefix))
