"""metadrive_compat: the patches refuse any MetaDrive but the one they were written for, in one line."""

import subprocess
import sys

import pytest

from msfsu_sim.metadrive_compat import METADRIVE_VERSION, MetaDriveVersionError, check_metadrive_version


def test_the_installed_metadrive_is_the_version_the_patches_were_written_for():
    check_metadrive_version()
    assert METADRIVE_VERSION == "0.4.3"


@pytest.mark.parametrize("installed", ["0.4.2.3", "0.4.3.1", "none"])
def test_another_metadrive_is_refused_in_one_line_naming_both_versions(installed):
    with pytest.raises(MetaDriveVersionError) as error:
        check_metadrive_version(installed)
    message = str(error.value)
    assert "\n" not in message and installed in message and "metadrive-simulator==0.4.3" in message


def test_the_asset_tools_neither_import_metadrive_nor_patch_it():
    """Patches come with the first engine (SimEnvironment); the asset tools only use the version and the paths."""
    code = ("import sys, msfsu_sim.assets, msfsu_sim.light_meshes, msfsu_sim.metadrive_compat as compat; "
            "print(compat.applied(), 'metadrive' in sys.modules)")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.split() == ["[]", "False"]
