import numpy as np

from msfsu_common.semantic_classes import SemanticClass, colourise
from msfsu_sim.semantics import CITYSCAPES_TO_CLASS, colours_to_class_ids


def test_every_metadrive_colour_maps_to_its_paper_class():
    colours = np.array([list(CITYSCAPES_TO_CLASS)], np.uint8)
    ids = colours_to_class_ids(colours)
    assert ids.tolist() == [[int(cls) for cls in CITYSCAPES_TO_CLASS.values()]]


def test_known_classes_by_name():
    image = np.array([[(128, 64, 128), (255, 255, 255), (244, 35, 232), (0, 0, 142), (220, 20, 60),
                       (70, 130, 180), (152, 251, 152), (55, 176, 189), (0, 0, 0)]], np.uint8)
    assert colours_to_class_ids(image).tolist() == [[0, 1, 2, 3, 3, 4, 4, 0, 4]]


def test_near_miss_colour_is_other():
    assert colours_to_class_ids(np.array([[(128, 64, 129)]], np.uint8))[0, 0] == SemanticClass.OTHER


def test_colourise_shape_and_road_colour():
    ids = np.zeros((2, 3), np.uint8)
    assert colourise(ids).shape == (2, 3, 3)
    assert colourise(ids)[0, 0].tolist() == [128, 64, 128]
