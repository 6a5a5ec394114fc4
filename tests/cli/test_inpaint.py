"""``car-napari inpaint``: the mask's convention, its size, its coverage (issue 32)."""

import numpy as np
import pytest
from skimage import io

from car_napari.cli import main


def _frame_and_mask(tmp_path, *, mask_shape=(48, 64), black_hole=False):
    """A 48x64 noise frame and a mask with a 2-pixel-wide scratch."""
    rng = np.random.default_rng(0)
    frame = (rng.random((48, 64)) * 200).astype(np.uint8)
    h, w = mask_shape
    mask = np.zeros((h, w), np.uint8)
    mask[:, w // 2 - w // 32 : w // 2 + w // 32] = 255
    if black_hole:
        mask = 255 - mask
    io.imsave(tmp_path / "frame.png", frame, check_contrast=False)
    io.imsave(tmp_path / "mask.png", mask, check_contrast=False)
    return frame, mask


def _inpaint(tmp_path, *options, out="out.png"):
    return main(["inpaint", str(tmp_path / "frame.png"), "-m", str(tmp_path / "mask.png"),
                 "-o", str(tmp_path / out), *options])


def test_a_mostly_masked_frame_is_refused_naming_the_options(tmp_path, capsys):
    _frame_and_mask(tmp_path, black_hole=True)
    assert _inpaint(tmp_path) == 2
    err = capsys.readouterr().err
    assert "93.8 % of the frame" in err and "--invert-mask" in err and "--force" in err
    assert not (tmp_path / "out.png").exists()  # refused before the work


def test_invert_mask_fills_the_black_hole(tmp_path, capsys):
    frame, _ = _frame_and_mask(tmp_path, black_hole=True)
    assert _inpaint(tmp_path, "--invert-mask") == 0
    restored = io.imread(tmp_path / "out.png")
    hole = np.zeros(frame.shape, bool)
    hole[:, 30:34] = True
    np.testing.assert_array_equal(restored[~hole], frame[~hole])
    assert "192 pixels restored (6.2 %)" in capsys.readouterr().err


def test_force_fills_a_mostly_masked_frame_and_says_so(tmp_path, capsys):
    frame, mask = _frame_and_mask(tmp_path)
    mask = np.full(mask.shape, 255, np.uint8)
    mask[:8, :8] = 0  # the known pixels: a corner
    io.imsave(tmp_path / "mask.png", mask, check_contrast=False)
    assert _inpaint(tmp_path, "--force") == 0
    err = capsys.readouterr().err
    assert "more than half; filling it (--force)" in err and "UserWarning" not in err
    np.testing.assert_array_equal(io.imread(tmp_path / "out.png")[:8, :8], frame[:8, :8])


def test_a_batch_with_one_mostly_masked_mask_is_refused_before_any_work(tmp_path, capsys):
    _frame_and_mask(tmp_path, black_hole=True)
    assert main(["inpaint", str(tmp_path / "frame.png"), "-m", str(tmp_path / "mask.png"),
                 "-o", str(tmp_path / "out")]) == 2
    assert "--invert-mask" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
    assert main(["inpaint", str(tmp_path / "frame.png"), "-m", str(tmp_path / "mask.png"),
                 "-o", str(tmp_path / "out"), "--invert-mask"]) == 0
    assert (tmp_path / "out" / "frame_inpainted.png").exists()


def test_a_mask_folder_is_checked_per_frame(tmp_path, capsys):
    _frame_and_mask(tmp_path, black_hole=True)
    masks = tmp_path / "masks"
    masks.mkdir()
    (tmp_path / "mask.png").rename(masks / "frame_mask.png")
    assert main(["inpaint", str(tmp_path / "frame.png"), "-m", str(masks),
                 "-o", str(tmp_path / "out")]) == 2
    assert "frame.png: failed: the mask frame_mask.png marks 93.8 %" in capsys.readouterr().err


def test_a_mask_of_another_size_is_resized_with_a_note(tmp_path, capsys):
    _frame_and_mask(tmp_path, mask_shape=(24, 32))  # half the frame's size
    assert _inpaint(tmp_path) == 0
    err = capsys.readouterr().err
    assert "note: mask mask.png resized from 32x24 to 64x48 (width x height)" in err
    _frame_and_mask(tmp_path, mask_shape=(96, 130))  # 1.6 % off: still resized
    assert _inpaint(tmp_path) == 0
    assert "resized from 130x96 to 64x48" in capsys.readouterr().err


def test_a_mask_of_another_aspect_ratio_is_refused(tmp_path, capsys):
    _frame_and_mask(tmp_path, mask_shape=(394 // 8, 625 // 8))  # the 625x394 mask
    assert _inpaint(tmp_path) == 2
    err = capsys.readouterr().err
    assert "is 78x49, the frame 64x48 (width x height)" in err
    assert "differ by 19.4 % (more than 2 %)" in err and "stretched" in err
    assert not (tmp_path / "out.png").exists()


def test_help_and_reading_say_damaged_is_brighter_than_mid_grey(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["inpaint", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert "brighter than mid-grey (above 127 in an 8-bit mask" in help_text
    assert "white (nonzero)" not in help_text
    frame, mask = _frame_and_mask(tmp_path)
    faint = np.where(mask > 0, 255, 0).astype(np.uint8)
    faint[:, :10] = 127  # an anti-aliased edge, not past mid-grey: known
    io.imsave(tmp_path / "mask.png", faint, check_contrast=False)
    assert _inpaint(tmp_path) == 0
    np.testing.assert_array_equal(io.imread(tmp_path / "out.png")[:, :10], frame[:, :10])
    assert "192 pixels restored" in capsys.readouterr().err


def test_a_mask_folder_may_name_masks_name_dash_mask(tmp_path, capsys):
    frame, mask = _frame_and_mask(tmp_path)
    masks = tmp_path / "masks"
    masks.mkdir()
    (tmp_path / "mask.png").rename(masks / "frame-mask.png")
    assert main(["inpaint", str(tmp_path / "frame.png"), "-m", str(masks),
                 "-o", str(tmp_path / "out")]) == 0
    assert (tmp_path / "out" / "frame_inpainted.png").exists()
    (masks / "frame-mask.png").unlink()
    assert main(["inpaint", str(tmp_path / "frame.png"), "-m", str(masks),
                 "-o", str(tmp_path / "out"), "--overwrite"]) == 2
    assert "looked for frame_mask.*, frame-mask.* and frame.*" in capsys.readouterr().err


@pytest.mark.parametrize("shape, source, suffix", [
    ((48, 64), "f.tif", ".tif"), ((48, 64), "f.png", ".png"), ((48, 64, 3), "f.tif", ".tif")])
def test_16_bit_stays_in_its_container_kind(tmp_path, shape, source, suffix):
    from car_napari.io.images import read_image, write_image

    frame = (np.random.default_rng(0).random(shape) * 60000).astype(np.uint16)
    write_image(tmp_path / source, frame)
    mask = np.zeros((48, 64), np.uint8)
    mask[:, 30:32] = 255
    io.imsave(tmp_path / "mask.png", mask, check_contrast=False)
    assert main(["inpaint", str(tmp_path / source), "-m", str(tmp_path / "mask.png"),
                 "-o", str(tmp_path / "out")]) == 0
    assert [p.name for p in (tmp_path / "out").iterdir()] == [f"f_inpainted{suffix}"]
    assert read_image(tmp_path / "out" / f"f_inpainted{suffix}").dtype == np.uint16


def test_a_mask_stack_is_refused(tmp_path, capsys):
    import tifffile

    _frame_and_mask(tmp_path)
    tifffile.imwrite(tmp_path / "masks.tif", np.zeros((5, 48, 64), np.uint8),
                     photometric="minisblack")
    assert main(["inpaint", str(tmp_path / "frame.png"), "-m", str(tmp_path / "masks.tif"),
                 "-o", str(tmp_path / "out.png")]) == 2
    assert "masks.tif holds a stack of shape (5, 48, 64)" in capsys.readouterr().err
