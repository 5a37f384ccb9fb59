import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from ros_graph import RosGraph  # noqa: E402


@pytest.fixture
def graph():
    ros_graph = RosGraph()
    yield ros_graph
    ros_graph.close()
