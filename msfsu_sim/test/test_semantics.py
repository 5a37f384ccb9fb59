import numpy as np

from msfsu_common.semantic_classes import SemanticClass, colourise
from msfsu_sim.semantics import CITYSCAPES_TO_CLASS, COLOUR_TOLERANCE, colours_to_class_ids


def test_every_metadrive_colour_maps_to_its_paper_class():
    colours = np.array([list(CITYSCAPES_TO_CLASS)], np.uint8)
    ids = colours_to_class_ids(colours)
    assert ids.tolist() == [[int(cls) for cls in CITYSCAPES_TO_CLASS.values()]]


def test_known_classes_by_name():
    image = np.array([[(128, 64, 128), (255, 255, 255), (244, 35, 232), (0, 0, 142), (220, 20, 60),
                       (70, 130, 180), (152, 251, 152), (55, 176, 189), (0, 0, 0)]], np.uint8)
    assert colours_to_class_ids(image).tolist() == [[0, 1, 2, 3, 3, 4, 4, 0, 4]]


def test_colours_near_a_class_take_it_and_farther_ones_are_other():
    image = np.array([[(211, 19, 58),  # MetaDrive's pedestrian as its semantic pass draws it
                       (128, 64, 128 + COLOUR_TOLERANCE), (128, 64, 128 + COLOUR_TOLERANCE + 1),
                       (0, 0, 0), (70, 130, 180)]], np.uint8)
    assert colours_to_class_ids(image).tolist() == [[SemanticClass.VEHICLE_OR_PEDESTRIAN, SemanticClass.ROAD,
                                                     SemanticClass.OTHER, SemanticClass.OTHER, SemanticClass.OTHER]]


def test_no_colour_is_near_two_palette_colours():
    palette = np.array(list(CITYSCAPES_TO_CLASS), int)
    apart = np.abs(palette[:, None] - palette[None]).max(-1)
    assert apart[~np.eye(len(palette), dtype=bool)].min() > 2 * COLOUR_TOLERANCE


def test_colourise_shape_and_road_colour():
    ids = np.zeros((2, 3), np.uint8)
    assert colourise(ids).shape == (2, 3, 3)
    assert colourise(ids)[0, 0].tolist() == [128, 64, 128]
