"""Dock widget "Texture synthesis": a texture becomes a model of a few kB, from
which any amount of it is synthesised (section 14.8, docs/texture.md)."""

from __future__ import annotations

from magicgui.widgets import CheckBox, ComboBox, FileEdit, Label, SpinBox
from napari.utils.notifications import show_info

from ..texture import (
    BTFModel,
    DynamicTextureModel,
    TextureModel,
    iter_fit_btf,
    iter_fit_dynamic_texture,
    iter_fit_texture,
)
from ._base import ModelWidget, guarded
from ._jobs import call

SINGLE, BTF, DYNAMIC = "single texture", "BTF: stack of illuminations", "dynamic: frames"
NOT_A_STACK = "it is not a stack (images along the first axis); choose 'single texture'."


class TextureSynthesisWidget(ModelWidget):
    """Fit a multiresolution CAR texture model to an image layer (or a
    rectangle on it), save or load it, and synthesise textures of any size.

    A stack is a BTF (one material under many illuminations) or a dynamic
    texture (the frames of a video).

    Parameters
    ----------
    napari_viewer : napari.Viewer
        The viewer.
    """

    no_model = "fit a model first (or load one)."
    control_labels = {"levels": "pyramid levels", "n_subspaces": "BTF subspaces",
                      "n_frames": "frames (dynamic)"}

    def __init__(self, napari_viewer):
        super().__init__(napari_viewer, size=512)
        self._source_name = "texture"
        self._input_shape = None
        self._mode = ComboBox(value=SINGLE, choices=[SINGLE, BTF, DYNAMIC], label="input",
                              tooltip="a stack is a BTF (one material, many illuminations) "
                                      "or a dynamic texture (frames of a video)")
        self._levels = SpinBox(value=3, min=1, max=6, label="pyramid levels")
        self._subspaces = SpinBox(value=4, min=1, max=64, label="BTF subspaces")
        self._frames = SpinBox(value=10, min=1, max=1000, label="frames (dynamic)")
        self._fit = self.action("Fit", self.start_fit)
        self._model_info = Label(value="no model")
        self._tileable = CheckBox(value=False, text="tileable (wraps seamlessly)")
        self._path = FileEdit(mode="w", filter="*.npz", label="model file")
        self._save = self.action("Save model", lambda *_: self.save_model(self._path.value),
                                 when=lambda: isinstance(self.model, TextureModel))
        self._load = self.action("Load model", lambda *_: self.load_model(self._path.value))
        self.arrange([self._mode, self._levels, self._subspaces, self._fit, self._model_info,
                      self._height, self._width, self._frames, self._seed, self._tileable,
                      self._synth],
                     after=[self._path, self._save, self._load])
        self._image.changed.connect(self._guess_mode)

    def _guess_mode(self, *_):
        layer = self._image.value
        if layer is None:
            return
        stack = layer.data.ndim - bool(getattr(layer, "rgb", False)) == 3
        if stack and self._mode.value == SINGLE:
            self._mode.value = BTF
        elif not stack:
            self._mode.value = SINGLE

    def _start(self):
        """Fit the model of the chosen input kind to the picked layer."""
        mode = self._mode.value
        levels = int(self._levels.value)
        if mode == SINGLE:
            data, channel_axis = self.input_array()
            job = iter_fit_texture(data, levels=levels, channel_axis=channel_axis)
        else:
            data, channel_axis = self.input_array(region=False, ndims=(3,), hint=NOT_A_STACK)
            if mode == BTF:
                job = iter_fit_btf(data, n_subspaces=min(int(self._subspaces.value), len(data)),
                               levels=levels, channel_axis=channel_axis)
            else:
                job = iter_fit_dynamic_texture(data, channel_axis=channel_axis)
        self._fitting = self._image.value.name, data.shape
        return self.run(job, done=self._fitted)

    def _fitted(self, model):
        self._source_name, self._input_shape = self._fitting
        self._set_model(model)

    def _set_model(self, model):
        self.model = model
        self.refresh_actions()
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

    def _synthesis(self, shape, seed):
        model = self.model
        if isinstance(model, DynamicTextureModel):
            job = call(model.synthesize, int(self._frames.value), shape, seed=seed)
        elif isinstance(model, BTFModel):
            job = call(model.synthesize, shape, seed=seed)
        else:
            job = call(model.synthesize, shape, seed=seed, tileable=bool(self._tileable.value))
        self._target = f"{self._source_name} synthesis", not isinstance(model, TextureModel)
        return self.run(job, done=self._show)

    def _show(self, synthesis):
        name, stacked = self._target
        # a single texture is (H, W[, C]); a BTF or dynamic synthesis has a leading axis
        rgb = synthesis.ndim == (4 if stacked else 3)
        layers = self._viewer.layers
        if name in layers and layers[name].data.shape == synthesis.shape:
            self.record.put(name, synthesis, None)
        else:
            self.record.replace(name, lambda name: self._viewer.add_image(synthesis, name=name,
                                                                          rgb=rgb))

    @guarded
    def save_model(self, path):
        """Write the texture model to ``path`` (an ``.npz`` file).

        Parameters
        ----------
        path : str or Path
            Where to write it.
        """
        if self.model is None:
            raise ValueError("there is no model to save: fit one first.")
        try:
            self.model.save(str(path))
        except OSError as exc:
            raise OSError(f"cannot write {path}: {exc}") from exc
        show_info(f"model saved to {path} ({self.model.nbytes} bytes of parameters)")

    @guarded
    def load_model(self, path):
        """Read a texture model from ``path`` (written by :meth:`save_model`).

        Parameters
        ----------
        path : str or Path
            The ``.npz`` file.
        """
        model = TextureModel.load(str(path))
        self._input_shape = None
        self._source_name = "texture model"
        self._set_model(model)
