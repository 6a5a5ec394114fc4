"""The "Scratch restoration" widget on a clip with motion (issue 13): Detect
leaves the moving content alone and finds the blotches, through the real
entry points of a real viewer."""

import numpy as np
import pytest
from scipy import ndimage
from skimage import data as skdata

from car_napari._widgets.inpainting import InpaintingWidget


@pytest.fixture
def widget(docked):
    return docked(InpaintingWidget, "Scratch restoration")


def _clip_with_motion(T=5):
    """A panned real image with a region of another real image moving over it
    (8-bit grey), a dark and a bright blotch on frame 2 (one on the region)."""
    scene = skdata.camera()
    patch = skdata.coins()[60:100, 70:120]
    frames, moving = [], []
    for t in range(T):
        frame = scene[100 + t : 196 + t, 120 + 2 * t : 248 + 2 * t].copy()
        r, c = 20 + 2 * t, 70 - 3 * t
        frame[r : r + 40, c : c + 50] = patch
        region = np.zeros(frame.shape, bool)
        region[r : r + 40, c : c + 50] = True
        frames.append(frame)
        moving.append(region)
    clip = np.stack(frames)
    clean = clip.copy()
    blotches = np.zeros(clip.shape, bool)
    blotches[2, 30:36, 60:67] = True  # on the moving region
    blotches[2, 70:76, 20:28] = True
    clip[2, 30:36, 60:67] = 0
    clip[2, 70:76, 20:28] = 255
    return clip, clean, blotches, np.stack(moving)


def test_detect_on_a_clip_with_motion_leaves_the_moving_region_unflagged(widget, qtbot):
    viewer, w = widget
    clip, clean, blotches, moving = _clip_with_motion()
    layer = viewer.add_image(clip, name="clip")
    w._image.value = layer
    job = w.detect()  # the button's entry point: runs in a worker
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    assert "proposed" in w._status.value
    proposed = viewer.layers["clip scratch mask"].data != 0
    assert proposed.shape == clip.shape
    near = ndimage.binary_dilation(blotches, structure=np.ones((1, 3, 3), bool),
                                   iterations=2)
    assert proposed[blotches].mean() > 0.9  # both blotches, the one on the moving region too
    assert not (proposed & moving & ~near).any()  # the moving region is left alone
    # (the line search, which Detect runs too, proposes the camera's tripod legs: still
    # vertical lines, off the moving region)
    # restoring with that mask leaves the moving region as it was
    job = w.start()
    qtbot.waitUntil(lambda: job.done, timeout=120000)
    out = viewer.layers["clip restored"].data
    keep = moving & ~near
    np.testing.assert_array_equal(out[keep], clip[keep])
    error = np.abs(out[blotches].astype(int) - clean[blotches]).mean()
    assert error < 0.25 * np.abs(clip[blotches].astype(int) - clean[blotches]).mean()
