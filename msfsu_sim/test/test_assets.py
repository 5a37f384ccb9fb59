import cv2
import numpy as np

from msfsu_sim.assets import CAR_MODELS, assets_ready, install_assets


def test_asset_folder_has_the_layout_metadrive_043_reads():
    folder = install_assets()  # idempotent: returns at once when already built
    assert assets_ready(folder)
    for car in CAR_MODELS:
        assert (folder / "models" / car / "vehicle.gltf").is_file()
    asphalt = cv2.imread(str(folder / "textures" / "asphalt" / "diff_2k.png"))
    assert asphalt.shape == (2048, 2048, 3)  # terrain.py paints crosswalks on a (2048, 2048, 3) view
    heightfield = cv2.imread(str(folder / "textures" / "terrain" / "heightfield.png"), cv2.IMREAD_UNCHANGED)
    assert heightfield.dtype == np.uint16 and heightfield.shape == (2048, 2048)
    assert (folder / "textures" / "grass1" / "GroundGrassGreen002_COL_1K.jpg").is_file()
