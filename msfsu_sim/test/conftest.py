"""One simulator for the whole test session: MetaDrive allows one engine per process, and a reset of a
new town is the slowest thing a test does."""

import os

import pytest

os.environ.setdefault("OMP_NUM_THREADS", "1")


@pytest.fixture(scope="session")
def sim():
    from msfsu_sim.assets import install_assets
    from msfsu_sim.environment import SimConfig, SimEnvironment

    install_assets()
    environment = SimEnvironment(SimConfig(labels=True))
    yield environment
    environment.close()
