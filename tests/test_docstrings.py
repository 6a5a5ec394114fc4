"""Docstrings: numpydoc validation of every public callable, and every doctest of the library.

Public: whatever ``car_napari.__all__`` and the subpackages' ``__all__`` name, and the public
methods their classes define. Each needs a docstring with a summary, its parameters documented
(and no unknown ones), Returns for a value and Yields for a generator, and an Examples section.
The doctests of every module but the widgets and the command line run here too."""

import doctest
import importlib
import inspect
import pkgutil

import pytest
from numpydoc.validate import Validator, get_doc_object, validate

import car_napari

PUBLIC_MODULES = [
    "car_napari", "car_napari.model", "car_napari.segmentation", "car_napari.mammography",
    "car_napari.restoration", "car_napari.inpainting", "car_napari.texture", "car_napari.io",
]
# a docstring, its summary, parameters documented and none unknown, Returns, Yields, Examples
REQUIRED = {"GL08", "SS01", "PR01", "PR02", "RT01", "YD01", "EX01"}
NO_DOCTESTS = ("car_napari._widgets", "car_napari.cli")


def _methods(cls):
    """The public methods a class defines itself (not those of tuple, object or a base)."""
    for attr, value in vars(cls).items():
        raw = value.__func__ if isinstance(value, staticmethod | classmethod) else value
        if not attr.startswith("_") and inspect.isfunction(raw):
            yield attr, raw


def _public_callables():
    """``{dotted public name: object}``, one name per object (the first found: top level)."""
    found, seen = {}, set()
    for module_name in PUBLIC_MODULES:
        module = importlib.import_module(module_name)
        for name in module.__all__:
            obj = getattr(module, name)
            if not callable(obj) or id(obj) in seen:
                continue
            seen.add(id(obj))
            found[f"{module_name}.{name}"] = obj
            if inspect.isclass(obj):
                for attr, method in _methods(obj):
                    if id(method) not in seen:
                        seen.add(id(method))
                        found[f"{module_name}.{name}.{attr}"] = method
    return found


PUBLIC = _public_callables()


class _RecordAwareValidator(Validator):
    """numpydoc's validator, except that a class may document its constructor's parameters as
    Attributes (the result records: NamedTuples and dataclasses)."""

    def __init__(self, obj_name):
        super().__init__(get_doc_object(Validator._load_obj(obj_name)))

    @property
    def parameter_mismatches(self):
        if not inspect.isclass(self.obj):
            return super().parameter_mismatches
        signature = set(self.signature_parameters)
        parameters = {p.replace("\\", "") for p in self.doc_all_parameters}
        attributes = {p.replace("\\", "") for p in self._doc_parameters(["Attributes"])}
        errors = []
        if signature - parameters - attributes:
            errors.append(("PR01", f"Parameters {signature - parameters - attributes} not "
                                   "documented"))
        if parameters - signature:
            errors.append(("PR02", f"Unknown parameters {parameters - signature}"))
        return errors


def _docstring_errors(name):
    result = validate(name, validator_cls=_RecordAwareValidator)
    return [f"{code}: {message}" for code, message in result["errors"] if code in REQUIRED]


def test_the_public_api_is_found():
    assert {"car_napari.segment", "car_napari.TextureModel", "car_napari.TextureModel.fit",
            "car_napari.iter_restore"} <= set(PUBLIC)


@pytest.mark.parametrize("name", sorted(PUBLIC))
def test_numpydoc(name):
    errors = _docstring_errors(name)
    assert not errors, f"{name}:\n  " + "\n  ".join(errors)


def test_the_validator_catches_a_bare_docstring():
    # an independent check of the rule set on a function of this file
    errors = _docstring_errors(f"{__name__}._an_undocumented_function")
    codes = {e.split(":")[0] for e in errors}
    assert {"PR01", "RT01", "EX01"} <= codes


def _an_undocumented_function(image, size):
    """Do something."""
    return image, size


def _library_modules(package=car_napari):
    """The package and its modules, depth first, never importing the widgets or the CLI."""
    yield package
    for info in pkgutil.iter_modules(package.__path__, package.__name__ + "."):
        if info.name.startswith(NO_DOCTESTS):
            continue
        module = importlib.import_module(info.name)
        if info.ispkg:
            yield from _library_modules(module)
        else:
            yield module


def _doctests():
    finder = doctest.DocTestFinder()
    tests = {}
    for module in _library_modules():
        for test in finder.find(module):
            if test.examples:
                tests[test.name] = test
    return tests


DOCTESTS = _doctests()


def test_the_doctests_are_found():
    assert len(DOCTESTS) >= 10


@pytest.mark.parametrize("name", sorted(DOCTESTS))
def test_doctest(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # examples that write files write them here
    test = DOCTESTS[name]
    test.globs = dict(test.globs)
    runner = doctest.DocTestRunner(
        optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE, verbose=False
    )
    report = []
    runner.run(test, out=report.append, clear_globs=False)
    assert runner.failures == 0, "".join(report)
