"""Dock widget "Texture retrieval": find a texture again under another
illumination, among the open image layers or the images of a folder."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from magicgui.widgets import ComboBox, FileEdit
from qtpy.QtCore import QSize, Qt
from qtpy.QtGui import QIcon, QImage, QPixmap
from qtpy.QtWidgets import QListWidget, QListWidgetItem

from .._progress import Progress
from ..io.images import IMAGE_SUFFIXES, read_image
from ..texture import iter_rank
from ._base import JobWidget
from ._layers import layer_array

LAYERS, FOLDER = "open image layers", "a folder"
THUMBNAIL = 64
EMPTY_GALLERY = ("the gallery is empty: open other image layers (of the same kind, grey or "
                 "colour, as the query) or choose a folder.")


def _small(image):
    """An (H, W[, 3]) image subsampled to about THUMBNAIL pixels a side,
    scaled to its own range, as (h, w, 3) uint8 (in the worker)."""
    image = np.asarray(image)
    step = max(1, max(image.shape[:2]) // THUMBNAIL)
    a = np.asarray(image[::step, ::step], dtype=np.float64)
    lo, hi = float(a.min()), float(a.max())
    a = np.zeros_like(a) if hi <= lo else (a - lo) / (hi - lo)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=2)
    return np.ascontiguousarray(np.round(a[..., :3] * 255).astype(np.uint8))


def _thumbnail(small):
    """A QIcon of a :func:`_small` thumbnail."""
    h, w = small.shape[:2]
    qimage = QImage(small.data, w, h, 3 * w, QImage.Format_RGB888).copy()
    return QIcon(QPixmap.fromImage(qimage))


def _rank_job(query, gallery, channel_axis, skipped):
    """The ranking, in the worker: the folder's images read (``gallery``
    entries ``("file", path)``; those of the other kind skipped), the
    ranking, the thumbnails. Returns ``(ranking, entries, images,
    thumbnails, skipped)``."""
    colour = channel_axis is not None
    entries, images = [], []
    for i, (entry, image) in enumerate(gallery):
        if image is None:  # a file
            yield Progress("reading", i / len(gallery), Path(entry[1]).name)
            try:
                image = read_image(entry[1])
            except ImportError:  # DICOM without pydicom
                skipped += 1
                continue
            if (image.ndim == 3) != colour:
                skipped += 1
                continue
        entries.append(entry)
        images.append(image)
    if not images:
        raise ValueError(EMPTY_GALLERY)
    ranking = yield from iter_rank(query, images, channel_axis=channel_axis)
    thumbnails = [_small(image) for image in images]
    return ranking, entries, images, thumbnails, skipped


class TextureRetrievalWidget(JobWidget):
    """Rank a gallery of textures by illumination-invariant CAR features
    (section 14.3, docs/texture.md): a query layer (or a rectangle on it)
    against the open image layers or a folder of images.

    Its only parameter, ``napari_viewer``, is documented by
    :class:`~car_napari._widgets._base.JobWidget`.
    """

    def __init__(self, napari_viewer):
        super().__init__(napari_viewer, image_label="query", region=True,
                         image_tooltip="the texture to look for (or the part of it inside "
                                       "the rectangle)")
        self.ranking = []  # (name, distance) nearest first
        self._entries = []  # gallery entries: ("layer", name) or ("file", path)
        self._source = ComboBox(value=LAYERS, choices=[LAYERS, FOLDER], label="gallery",
                                tooltip="where the textures to compare come from: the "
                                        "viewer's image layers, or a folder of images")
        self._folder = FileEdit(mode="d", label="folder",
                                tooltip="the folder of images to compare (for a folder "
                                        "gallery)")
        self._run = self.action("Rank", self.start,
                                tooltip="rank the gallery by likeness to the query, most "
                                        "alike first")
        self._results = QListWidget()
        self._results.setIconSize(QSize(THUMBNAIL, THUMBNAIL))
        self._results.setMinimumHeight(200)
        self.arrange([self._source, self._folder, self._run], fill=self._results)
        self._results.itemClicked.connect(lambda item: self.show(self._results.row(item)))

    def _gallery(self, query_layer, query_colour, use_region):
        """(gallery, skipped): the gallery's ``(entry, data)`` pairs with the
        query's colour-ness, layer data as views; a file's data is None (the
        worker reads it)."""
        gallery, skipped = [], 0
        if self._source.value == LAYERS:
            for layer in self._viewer.layers:
                if getattr(layer, "_type_string", "") != "image":
                    continue
                if layer is query_layer and not use_region:
                    continue  # the query itself would always come first
                try:
                    data, channel_axis = layer_array(layer, copy=False)
                except ValueError:
                    skipped += 1
                    continue
                if (channel_axis is not None) != query_colour:
                    skipped += 1
                    continue
                gallery.append((("layer", layer.name), data))
            if not gallery:
                raise ValueError(EMPTY_GALLERY)
        else:
            folder = Path(self._folder.value)
            if not folder.is_dir():
                raise ValueError(f"{folder} is not a folder; choose one with images.")
            gallery = [(("file", path), None) for path in sorted(folder.iterdir())
                       if path.suffix.lower() in IMAGE_SUFFIXES]
            if not gallery:
                raise ValueError(EMPTY_GALLERY)
        return gallery, skipped

    def _start(self):
        """Rank the gallery by distance to the query: the main thread only
        picks the layers (their data as views) or the folder's files; the
        worker reads, describes and ranks them."""
        layer, region = self._image.value, self._region.value
        query, channel_axis = layer_array(layer, region, copy=False)
        use_region = region is not None and len(region.data) > 0
        gallery, skipped = self._gallery(layer, channel_axis is not None, use_region)
        return self.run(_rank_job(query, gallery, channel_axis, skipped),
                        done=self._show_ranking)

    def _name(self, entry):
        kind, value = entry
        return value if kind == "layer" else Path(value).name

    def _show_ranking(self, result):
        (indices, distances), self._entries, self._images, thumbnails, self._skipped = result
        self._results.clear()
        self.ranking = []
        order = [int(i) for i in indices]
        self._order = order
        for rank_, (i, dist) in enumerate(zip(order, distances, strict=True), start=1):
            name = self._name(self._entries[i])
            self.ranking.append((name, float(dist)))
            item = QListWidgetItem(_thumbnail(thumbnails[i]), f"{rank_}. {name}   {dist:.3g}")
            item.setData(Qt.UserRole, i)
            self._results.addItem(item)
        note = f" ({self._skipped} of another kind skipped)" if self._skipped else ""
        self._status.value = f"{len(order)} ranked{note}"

    def show(self, row):
        """Show the gallery entry at ``row`` of the ranking: select its layer,
        or open the file as a layer."""
        i = self._order[row]
        kind, value = self._entries[i]
        if kind == "layer":
            layer = self._viewer.layers[value]
        else:
            name = f"retrieved: {Path(value).name}"
            if name in self._viewer.layers:
                layer = self._viewer.layers[name]
            else:
                image = self._images[i]
                layer = self._viewer.add_image(image, name=name, rgb=image.ndim == 3)
        layer.visible = True
        self._viewer.layers.selection.active = layer
        return layer
