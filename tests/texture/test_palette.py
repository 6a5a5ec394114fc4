"""The palette's covered radii (texture/_palette.py, issue 34): every colour a
synthesis keeps lies near a colour of the input, checked by brute force."""

import numpy as np
import pytest
from skimage import data as skdata

from car_napari.texture import TextureModel, _palette


def _nearest_input_distance(points, pixels):
    """Plain NumPy: the distance of each point to its nearest input pixel."""
    best = np.full(len(points), np.inf)
    for start in range(0, len(pixels), 2000):
        part = pixels[start:start + 2000]
        d2 = ((points[:, None, :] - part[None]) ** 2).sum(-1)
        best = np.minimum(best, d2.min(axis=1))
    return np.sqrt(best)


def _curve_pixels(rng, n=6000):
    """Colours along a bent curve plus a tight cluster: elongated, not round."""
    t = rng.random(n)
    curve = np.stack([0.1 + 0.8 * t, 0.2 + 0.5 * t ** 2, 0.6 - 0.4 * t], axis=1)
    blob = rng.normal([0.8, 0.2, 0.7], 0.02, (n // 4, 3))
    return np.clip(np.concatenate([curve + rng.normal(0, 0.01, curve.shape), blob]), 0, 1)


@pytest.mark.parametrize("d", [2, 3, 4])
def test_directions_are_unit_vectors(d):
    directions = _palette._directions(d)
    assert directions.shape == (_palette._DIRECTIONS, d)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0, atol=1e-12)


@pytest.mark.parametrize("d", [2, 3])
def test_colour_grid_flags_only_points_within_the_tolerance(d):
    rng = np.random.default_rng(d)
    pixels = _curve_pixels(rng)[:, :d]
    tolerance = 0.05
    flags, low, cell = _palette._colour_grid(pixels, tolerance)
    sides = np.array(flags.shape)

    def flagged(points):
        index = np.minimum(((points - low) / cell).astype(np.int64), sides - 1)
        return flags[tuple(index.T)]

    assert flagged(pixels).all()  # every input colour's own cell
    points = low + rng.random((4000, d)) * (pixels.max(0) - low)
    distance = _nearest_input_distance(points, pixels)
    assert (distance[flagged(points)] <= tolerance + 1e-12).all()
    # and the grid is not empty of meaning: far points are not flagged
    assert not flagged(points[distance > 3 * tolerance]).any()


def test_covered_radius_probes_lie_near_input_colours():
    # every probe of a kept ball (in its colour's Voronoi cell, within the
    # range) lies within the tolerance of an input colour, by brute force
    rng = np.random.default_rng(0)
    pixels = _curve_pixels(rng)
    centres, r95 = _palette.fit_palette(pixels.reshape(60, -1, 3), 12)
    # fit_palette's radii are already cut: recompute the uncut ones' cut here
    radius = _palette._covered_radius(pixels, centres, r95 + 0.1)
    assert (radius <= r95 + 0.1).all()
    np.testing.assert_array_equal(_palette._covered_radius(pixels, centres, r95), r95)
    tolerance = _palette._TOLERANCE * float((pixels.max(0) - pixels.min(0)).max())
    directions = _palette._directions(3)
    for c in range(len(centres)):
        rings = np.linspace(0, radius[c], 7)[1:]
        probes = (centres[c] + rings[:, None, None] * directions[None]).reshape(-1, 3)
        own = np.argmin(((probes[:, None] - centres[None]) ** 2).sum(-1), axis=1) == c
        within = np.all((probes >= pixels.min(0)) & (probes <= pixels.max(0)), axis=1)
        keep = own & within
        # the rings between the tested cell multiples: a cell's slack
        slack = tolerance / (2 * np.sqrt(3))
        assert (_nearest_input_distance(probes[keep], pixels) <= tolerance + slack).all()


def test_covered_radius_of_a_line_and_of_a_filled_cube():
    rng = np.random.default_rng(1)
    t = rng.random(20000)
    line = np.stack([t, t, t], axis=1) * 0.8 + 0.1
    width = float(np.ptp(line[:, 0]))
    tolerance = _palette._TOLERANCE * width
    centre = np.array([[0.5, 0.5, 0.5]])
    # off the line nothing is near: the ball shrinks to within the tolerance
    # (the grid is cautious: at least its first ring, a cell, stays)
    radius = _palette._covered_radius(line, centre, np.array([0.3]))
    assert tolerance / (2 * np.sqrt(3)) - 1e-12 <= radius[0] <= tolerance
    # a cube full of colours covers any ball within it
    cube = rng.random((60000, 3)) * 0.8 + 0.1
    np.testing.assert_array_equal(_palette._covered_radius(cube, centre, np.array([0.3])), 0.3)


def test_synthesis_keeps_colours_near_the_input_colours():
    # two colour families (green grass and a saturated red and blue patch):
    # the snap leaves no synthesised colour far from every input colour
    image = skdata.astronaut()[300:428, 30:158].astype(float) / 255
    image[40:70, 40:70] = [0.9, 0.1, 0.1]
    image[80:100, 10:50] = [0.1, 0.2, 0.9]
    image += np.random.default_rng(0).normal(0, 0.01, image.shape)
    model = TextureModel.fit(image, levels=2)
    out = model.synthesize((96, 96), seed=0)
    pixels = image.reshape(-1, 3)
    tolerance = _palette._TOLERANCE * float((pixels.max(0) - pixels.min(0)).max())
    distance = _nearest_input_distance(out.reshape(-1, 3), pixels)
    # probes are a ring of directions: a pixel between them is a little farther
    assert distance.max() <= 1.5 * tolerance
