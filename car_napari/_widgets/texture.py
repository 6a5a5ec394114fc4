"""Dock widget "Texture synthesis": a texture becomes a model of a few kB, from
which any amount of it is synthesised (SPEC 7)."""

from __future__ import annotations

from magicgui.widgets import (
    CheckBox,
    ComboBox,
    Container,
    FileEdit,
    Label,
    ProgressBar,
    PushButton,
    SpinBox,
    create_widget,
)
from napari.utils.notifications import show_error, show_info

import numpy as np

from ..texture.btf import BTFModel
from ..texture.dynamic import DynamicTextureModel
from ..texture import TextureModel
from ._jobs import Job
from ._layers import image_data

SINGLE, BTF, DYNAMIC = "single texture", "BTF: stack of illuminations", "dynamic: frames"


def _fit_job(data, channel_axis, levels, mode, n_subspaces):
    yield 0.05
    if mode == BTF:
        return BTFModel.fit(data, n_subspaces=min(n_subspaces, len(data)), levels=levels,
                            channel_axis=channel_axis)
    if mode == DYNAMIC:
        return DynamicTextureModel.fit(data, channel_axis=channel_axis)
    return TextureModel.fit(data, levels=levels, channel_axis=channel_axis)


def _synthesis_job(model, shape, seed, tileable, n_frames):
    yield 0.05
    if isinstance(model, DynamicTextureModel):
        return model.synthesize(n_frames, shape, seed=seed)
    if isinstance(model, BTFModel):
        return model.synthesize(shape, seed=seed)
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
        self._mode = ComboBox(value=SINGLE, choices=[SINGLE, BTF, DYNAMIC], label="input",
                              tooltip="a stack is a BTF (one material, many illuminations) "
                                      "or a dynamic texture (frames of a video)")
        self._levels = SpinBox(value=3, min=1, max=6, label="pyramid levels")
        self._subspaces = SpinBox(value=4, min=1, max=64, label="BTF subspaces")
        self._frames = SpinBox(value=10, min=1, max=1000, label="frames (dynamic)")
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
        self.extend([self._image, self._region, self._mode, self._levels, self._subspaces,
                     self._fit, self._model_info, self._height, self._width, self._frames,
                     self._seed, self._tileable, self._synthesize, self._cancel,
                     self._progress, self._path, self._save, self._load])
        self._image.changed.connect(self._guess_mode)
        self._fit.changed.connect(self.start_fit)
        self._synthesize.changed.connect(self.start_synthesis)
        self._cancel.changed.connect(self.cancel)
        self._save.changed.connect(lambda *_: self.save_model(self._path.value))
        self._load.changed.connect(lambda *_: self.load_model(self._path.value))

    def cancel(self, *_):
        if self._job is not None:
            self._job.cancel()

    def _guess_mode(self, *_):
        layer = self._image.value
        if layer is None:
            return
        stack = layer.data.ndim - bool(getattr(layer, "rgb", False)) == 3
        if stack and self._mode.value == SINGLE:
            self._mode.value = BTF
        elif not stack:
            self._mode.value = SINGLE

    def _stack_data(self, layer):
        """(copy, channel_axis) of a (n, H, W[, C]) layer."""
        if layer is None:
            raise ValueError("no image layer selected: open an image (or a sample) first.")
        rgb = bool(getattr(layer, "rgb", False))
        data = np.array(layer.data, copy=True)
        if data.ndim - rgb != 3:
            raise ValueError(f"layer {layer.name!r} is not a stack (images along the first "
                             "axis); choose 'single texture'.")
        return (data[..., :3] if rgb else data), (-1 if rgb else None)

    def start_fit(self, *_):
        mode = self._mode.value
        try:
            layer = self._image.value
            if mode == SINGLE:
                data, channel_axis = image_data(layer, self._region.value)
            else:
                data, channel_axis = self._stack_data(layer)
        except ValueError as exc:
            show_error(str(exc))
            return None
        self._source_name = layer.name
        self._input_shape = data.shape
        self._job = Job(_fit_job, data, channel_axis, int(self._levels.value), mode,
                        int(self._subspaces.value), progress=self._progress,
                        cancel=self._cancel, buttons=(self._fit, self._synthesize),
                        on_done=self._set_model)
        return self._job

    def _set_model(self, model):
        self.model = model
        self._synthesize.enabled = True
        self._save.enabled = isinstance(model, TextureModel)
        self._describe()

    def _describe(self):
        model = self.model
        if not isinstance(model, TextureModel):
            kind = ("BTF, " + f"{len(model.models)} subspaces"
                    if isinstance(model, BTFModel) else "dynamic 3.5D")
            self._model_info.value = (f"{kind}, {model.nbytes} bytes, "
                                      f"{model.compression_ratio(self._input_shape):.0f}:1")
            return
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
                        bool(self._tileable.value), int(self._frames.value),
                        progress=self._progress,
                        cancel=self._cancel, buttons=(self._fit, self._synthesize),
                        on_done=self._show)
        return self._job

    def _show(self, texture):
        name = f"{self._source_name} synthesis"
        # a single texture is (H, W[, C]); a BTF or dynamic synthesis has a leading axis
        rgb = texture.ndim == (3 if isinstance(self.model, TextureModel) else 4)
        if name in self._viewer.layers and self._viewer.layers[name].data.shape == texture.shape:
            self._viewer.layers[name].data = texture
        else:
            if name in self._viewer.layers:
                self._viewer.layers.remove(name)
            self._viewer.add_image(texture, name=name, rgb=rgb)

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
