"""Dock widget "Texture synthesis": a texture becomes a model of a few kB, from
which any amount of it is synthesised (SPEC 7)."""

from __future__ import annotations

from magicgui.widgets import (
    CheckBox,
    Container,
    FileEdit,
    Label,
    ProgressBar,
    PushButton,
    SpinBox,
    create_widget,
)
from napari.utils.notifications import show_error, show_info

from ..texture import TextureModel
from ._jobs import Job
from ._layers import image_data


def _fit_job(data, channel_axis, levels):
    yield 0.05
    return TextureModel.fit(data, levels=levels, channel_axis=channel_axis)


def _synthesis_job(model, shape, seed, tileable):
    yield 0.05
    return model.synthesize(shape, seed=seed, tileable=tileable)


class TextureSynthesisWidget(Container):
    """Fit a multiresolution CAR texture model to an image layer (or a
    rectangle on it), save or load it, and synthesise textures of any size."""

    def __init__(self, napari_viewer):
        super().__init__(labels=True)
        self._viewer = napari_viewer
        self.model: TextureModel | None = None
        self._source_name = "texture"
        self._input_shape = None
        self._job = None
        self._image = create_widget(annotation="napari.layers.Image", label="image")
        self._region = create_widget(
            annotation="napari.layers.Shapes", label="rectangle",
            options={"nullable": True, "tooltip": "optional: fit only inside its first shape"},
        )
        self._levels = SpinBox(value=3, min=1, max=6, label="pyramid levels")
        self._fit = PushButton(text="Fit")
        self._model_info = Label(value="no model")
        self._height = SpinBox(value=512, min=1, max=8192, label="height")
        self._width = SpinBox(value=512, min=1, max=8192, label="width")
        self._seed = SpinBox(value=0, min=0, max=2**31 - 1, label="seed")
        self._tileable = CheckBox(value=False, text="tileable (wraps seamlessly)")
        self._synthesize = PushButton(text="Synthesize", enabled=False)
        self._cancel = PushButton(text="Cancel", enabled=False)
        self._progress = ProgressBar(value=0, min=0, max=100, label="progress")
        self._path = FileEdit(mode="w", filter="*.npz", label="model file")
        self._save = PushButton(text="Save model", enabled=False)
        self._load = PushButton(text="Load model")
        self.extend([self._image, self._region, self._levels, self._fit, self._model_info,
                     self._height, self._width, self._seed, self._tileable, self._synthesize,
                     self._cancel, self._progress, self._path, self._save, self._load])
        self._fit.changed.connect(self.start_fit)
        self._synthesize.changed.connect(self.start_synthesis)
        self._cancel.changed.connect(self.cancel)
        self._save.changed.connect(lambda *_: self.save_model(self._path.value))
        self._load.changed.connect(lambda *_: self.load_model(self._path.value))

    def cancel(self, *_):
        if self._job is not None:
            self._job.cancel()

    def start_fit(self, *_):
        try:
            layer = self._image.value
            data, channel_axis = image_data(layer, self._region.value)
        except ValueError as exc:
            show_error(str(exc))
            return None
        self._source_name = layer.name
        self._input_shape = data.shape
        self._job = Job(_fit_job, data, channel_axis, int(self._levels.value),
                        progress=self._progress, cancel=self._cancel,
                        buttons=(self._fit, self._synthesize), on_done=self._set_model)
        return self._job

    def _set_model(self, model):
        self.model = model
        self._synthesize.enabled = self._save.enabled = True
        self._describe()

    def _describe(self):
        model = self.model
        text = f"orders {list(model.orders)} per band, {model.nbytes} bytes"
        if self._input_shape is not None:
            text += f", {model.compression_ratio(self._input_shape):.0f}:1"
        if model.fallbacks:
            text += f"; {len(model.fallbacks)} unstable band(s) refitted lower"
        self._model_info.value = text

    def start_synthesis(self, *_):
        if self.model is None:
            show_error("fit a model first (or load one).")
            return None
        shape = (int(self._height.value), int(self._width.value))
        self._job = Job(_synthesis_job, self.model, shape, int(self._seed.value),
                        bool(self._tileable.value), progress=self._progress,
                        cancel=self._cancel, buttons=(self._fit, self._synthesize),
                        on_done=self._show)
        return self._job

    def _show(self, texture):
        name = f"{self._source_name} synthesis"
        rgb = texture.ndim == 3
        if name in self._viewer.layers and self._viewer.layers[name].data.shape == texture.shape:
            self._viewer.layers[name].data = texture
        else:
            if name in self._viewer.layers:
                self._viewer.layers.remove(name)
            lo, hi = self.model.value_range.min(), self.model.value_range.max()
            self._viewer.add_image(texture, name=name, rgb=rgb,
                                   contrast_limits=None if rgb else (lo, hi))

    def save_model(self, path):
        if self.model is None:
            show_error("there is no model to save: fit one first.")
            return
        try:
            self.model.save(str(path))
        except OSError as exc:
            show_error(f"cannot write {path}: {exc}")
            return
        show_info(f"model saved to {path} ({self.model.nbytes} bytes of parameters)")

    def load_model(self, path):
        try:
            model = TextureModel.load(str(path))
        except (ValueError, OSError) as exc:
            show_error(str(exc))
            return
        self._input_shape = None
        self._source_name = "texture model"
        self._set_model(model)
