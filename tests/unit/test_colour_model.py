"""The colour model (``perception.colour_model``): by full colour a cloth in the shade is a
colour the object never showed; by hue alone it is still the object, while its
surroundings' hue and a hue neither showed are not."""

import numpy as np

from perception.colour_model import ColourModel


def test_hue_alone_keeps_a_cloth_in_the_shade_and_still_tells_it_from_its_surroundings():
    rng = np.random.default_rng(0)
    rgb = np.empty((120, 160, 3), np.float64)
    rgb[:] = (150, 150, 145)  # a grey table
    cloth = np.zeros((120, 160), bool)
    cloth[30:90, 40:120] = True
    rgb[cloth] = (70, 90, 200)  # a blue cloth
    rgb = np.clip(rgb + rng.normal(0, 2, rgb.shape), 0, 255).astype(np.uint8)
    model = ColourModel(rgb, cloth)
    assert model.informative
    shade = rgb.copy()
    shade[cloth] = (rgb[cloth] * 0.5).astype(np.uint8)  # the same cloth in a fold's shade
    shade[:20, :40] = (200, 60, 50)  # a red arm
    full, hue = model.probability(shade), model.chroma_probability(shade)
    inner = np.zeros_like(cloth)
    inner[36:84, 46:114] = True  # away from the outline the lookups blur
    assert np.median(full[inner]) < 0.5  # by full colour the shaded cloth is not the object
    assert np.percentile(hue[inner], 5) > 0.5  # by hue it is
    assert hue[100:, :].max() < 0.5  # the table is not
    assert hue[2:18, 2:38].max() < 0.5  # nor the arm
