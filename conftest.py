"""Test-session environment: ROS traffic stays on this host, and the session owns a ROS domain id.

Set here (the repository root) so it applies to every test directory and to the processes tests start.
"""

import os

import pytest
from domain_coordinator import domain_id

from msfsu_common.ros_env import configure_ros_environment

configure_ros_environment()
_domain = domain_id()


def pytest_configure(config: pytest.Config) -> None:
    os.environ["ROS_DOMAIN_ID"] = str(_domain.__enter__())


def pytest_unconfigure(config: pytest.Config) -> None:
    _domain.__exit__(None, None, None)
