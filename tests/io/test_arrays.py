"""Large images: zarr, OME-Zarr and TIFF opened as arrays and written by tiles."""

import numpy as np
import pytest
import tifffile

from car_napari.io.arrays import create_array, is_large_path, open_array


def _image(shape, dtype=np.uint16):
    return np.random.default_rng(0).integers(0, 60000, shape).astype(dtype)


@pytest.mark.parametrize("name", ["a.zarr", "a.ome.zarr", "a.tif"])
@pytest.mark.parametrize("shape", [(70, 50), (70, 50, 3)])
def test_written_by_tiles_read_back_as_written(tmp_path, name, shape):
    if name.endswith(".zarr"):
        pytest.importorskip("zarr")
    image = _image(shape)
    out = create_array(tmp_path / name, shape, np.uint16, chunks=32)
    for r in range(0, 70, 32):  # by bands, as the tiled jobs write
        out[r : r + 32, :] = image[r : r + 32]
    if hasattr(out, "flush"):
        out.flush()
    del out
    back = open_array(tmp_path / name)
    assert back.shape == shape and np.dtype(back.dtype) == np.uint16
    np.testing.assert_array_equal(np.asarray(back[:]), image)


def test_an_ome_zarr_is_channels_first_on_disk(tmp_path):
    zarr = pytest.importorskip("zarr")
    image = _image((40, 30, 3))
    create_array(tmp_path / "c.ome.zarr", image.shape, np.uint16)[:, :] = image
    group = zarr.open_group(str(tmp_path / "c.ome.zarr"), mode="r")
    axes = [a["name"] for a in group.attrs["multiscales"][0]["axes"]]
    assert axes == ["c", "y", "x"] and group["0"].shape == (3, 40, 30)
    np.testing.assert_array_equal(group["0"][1], image[..., 1])


def test_a_compressed_tiff_is_read_by_tiles(tmp_path):
    pytest.importorskip("zarr")
    image = _image((64, 48, 3), np.uint8)
    tifffile.imwrite(tmp_path / "z.tif", image, compression="zlib", tile=(32, 32),
                     photometric="rgb")
    back = open_array(tmp_path / "z.tif")
    np.testing.assert_array_equal(np.asarray(back[10:40, 5:20]), image[10:40, 5:20])


def test_paths_and_errors(tmp_path):
    assert is_large_path("x.ome.zarr/") and is_large_path("y.TIF")
    assert not is_large_path("z.png")
    with pytest.raises(ValueError, match="no such file"):
        open_array(tmp_path / "missing.zarr")
    with pytest.raises(ValueError, match="use .zarr, .ome.zarr or .tif"):
        create_array(tmp_path / "x.png", (4, 4), np.uint8)
