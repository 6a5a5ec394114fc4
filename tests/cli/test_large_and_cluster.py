"""Command line, issue 16: large images zarr to zarr (restore, inpaint), and
the batch forms of inpaint, fit-texture and retrieve on a 2-worker cluster
against the serial run."""

import numpy as np
import pytest
from skimage import data as skdata
from skimage import io

from car_napari.cli import main


def _from_unit(values):
    return np.round(np.clip(values, 0, 1) * 255).astype(np.uint8)


def test_restore_zarr_to_zarr_tiff_and_ome_zarr(tmp_path, capsys):
    pytest.importorskip("zarr")
    from car_napari.io.arrays import create_array, open_array
    from car_napari.restoration import restore

    rng = np.random.default_rng(0)
    image = np.clip(skdata.camera()[:160, :200] + rng.normal(0, 12, (160, 200)), 0, 255)
    image = image.astype(np.uint8)
    store = create_array(tmp_path / "big.zarr", image.shape, np.uint8, chunks=64)
    store[:] = image
    expected = _from_unit(restore(image))
    for name in ("out.zarr", "out.tif", "out.ome.zarr"):
        assert main(["restore", str(tmp_path / "big.zarr"), "-o", str(tmp_path / name),
                     "--tile", "64"]) == 0
        got = np.asarray(open_array(tmp_path / name)[:])
        assert got.dtype == np.uint8
        np.testing.assert_array_equal(got, expected)
    assert "restored (160x200)" in capsys.readouterr().err
    # two inputs and a large output: a clear error, nothing written
    assert main(["restore", str(tmp_path / "big.zarr"), str(tmp_path / "big.zarr"),
                 "-o", str(tmp_path / "two.zarr")]) == 2
    assert "give one input" in capsys.readouterr().err


def test_inpaint_a_zarr_clip(tmp_path):
    pytest.importorskip("zarr")
    from car_napari.inpainting import inpaint
    from car_napari.io.arrays import create_array, open_array

    base = skdata.camera()[:64, :80]
    clip = np.stack([np.roll(base, 2 * t, axis=1) for t in range(3)])
    store = create_array(tmp_path / "clip.zarr", clip.shape, np.uint8, chunks=32)
    store[:] = clip
    mask = np.zeros((64, 80), np.uint8)
    mask[10:50, 30:33] = 255
    io.imsave(tmp_path / "mask.png", mask, check_contrast=False)
    assert main(["inpaint", str(tmp_path / "clip.zarr"), "-m", str(tmp_path / "mask.png"),
                 "-o", str(tmp_path / "out.zarr")]) == 0
    np.testing.assert_array_equal(open_array(tmp_path / "out.zarr")[:],
                                  inpaint(clip, mask > 0))


def test_zarr_without_the_extra_says_what_to_install(tmp_path, capsys, monkeypatch):
    import sys

    (tmp_path / "big.zarr").mkdir()
    monkeypatch.setitem(sys.modules, "zarr", None)  # as if not installed
    assert main(["restore", str(tmp_path / "big.zarr"), "-o", str(tmp_path / "o.zarr")]) == 2
    assert "pip install 'car-napari[cluster]'" in capsys.readouterr().err


@pytest.fixture(scope="module")
def cluster():
    distributed = pytest.importorskip("dask.distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as local:
        yield local.scheduler_address


def _files(folder):
    return sorted(p.name for p in folder.iterdir())


def test_batches_on_two_workers_write_what_the_serial_run_writes(tmp_path, capsys, cluster):
    frames, masks = tmp_path / "frames", tmp_path / "masks"
    frames.mkdir()
    masks.mkdir()
    textures = [skdata.brick(), skdata.gravel(), skdata.grass()]
    for k, texture in enumerate(textures):
        frame = texture[:48, :48].copy()
        frame[:, 20 + k : 22 + k] = 255
        io.imsave(frames / f"f{k}.png", frame)
        mask = np.zeros((48, 48), np.uint8)
        mask[:, 20 + k : 22 + k] = 255
        io.imsave(masks / f"f{k}_mask.png", mask, check_contrast=False)
    (frames / "broken.png").write_text("not an image")
    for runs in (["--workers", "1"], ["--scheduler", cluster]):
        out = tmp_path / ("cluster" if "--scheduler" in runs else "serial")
        assert main(["inpaint", str(frames), "-m", str(masks), "-o", str(out / "inpaint"),
                     *runs]) == 1  # the broken file fails alone
        assert main(["fit-texture", str(frames / "f*.png"), "-o", str(out / "models"),
                     "--levels", "1", "--order", "1", *runs]) == 0
    err = capsys.readouterr().err
    assert err.count("broken.png: failed") == 2
    serial, parallel = tmp_path / "serial", tmp_path / "cluster"
    assert _files(serial / "inpaint") == [f"f{k}_inpainted.png" for k in range(3)]
    for name in _files(serial / "inpaint"):
        np.testing.assert_array_equal(io.imread(parallel / "inpaint" / name),
                                      io.imread(serial / "inpaint" / name))
    assert _files(serial / "models") == ["f0.npz", "f1.npz", "f2.npz"]
    for name in _files(serial / "models"):
        a, b = np.load(serial / "models" / name), np.load(parallel / "models" / name)
        assert sorted(a.files) == sorted(b.files)
        for key in a.files:
            np.testing.assert_array_equal(a[key], b[key])
    # retrieve: the gallery's features on the workers, the same ranking
    rankings = []
    for runs in ([], ["--scheduler", cluster]):
        assert main(["retrieve", str(frames / "f0.png"), str(frames), *runs]) == 1
        rankings.append(capsys.readouterr().out)
    assert rankings[0] == rankings[1] and rankings[0].splitlines()[0].endswith("f0.png")


class _Block:
    def __init__(self, start, folder):
        self.start, self.folder, self.name = start, folder, f"block {start}"


def _prepare(block, on_progress):
    if block.start == 2:
        raise ValueError("damaged block")
    return np.arange(block.start, block.start + 3)  # e.g. the block's masks


def _finish(block, prepared, carried, on_progress):
    value = prepared.sum() + (0 if carried is None else int(carried[-1]))
    np.save(block.folder / f"{block.start}.npy", np.array([value]))
    return f"value {value}", np.array([value])  # carried to the next block


def test_chained_blocks_on_two_workers_are_the_serial_chain(tmp_path, capsys, cluster):
    from types import SimpleNamespace

    from car_napari.cli._batch import run_blocks

    outputs = {}
    for name, options in (("serial", None), ("cluster", SimpleNamespace(scheduler=cluster))):
        folder = tmp_path / name
        folder.mkdir()
        blocks = [_Block(k, folder) for k in range(5)]
        assert run_blocks(blocks, _prepare, _finish, options=options) == 1
        outputs[name] = {k: int(np.load(folder / f"{k}.npy")[0]) for k in (0, 1, 3, 4)}
    # block 3 starts afresh after the failed block 2; 4 carries 3's value
    assert outputs["serial"] == {0: 3, 1: 9, 3: 12, 4: 27} == outputs["cluster"]
    captured = capsys.readouterr()
    assert captured.err.count("block 2: failed: damaged block") == 2
    assert captured.out.count("block 4: value 27") == 2
