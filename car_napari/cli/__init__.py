"""Command line: ``car-napari fit | fit-texture | synthesize | retrieve | segment |
mammo | restore | inpaint | descratch``.

One module per command (its options and what it runs); they use only the
public core API and :mod:`car_napari.io`: no Qt, no napari.
"""

from __future__ import annotations

import argparse
import sys

from . import (
    _descratch,
    _fit,
    _fit_texture,
    _inpaint,
    _mammo,
    _restore,
    _retrieve,
    _segment,
    _synthesize,
)
from ._batch import INPUT_ERRORS, BatchFailed
from ._console import quiet_mode
from ._files import expand_inputs

__all__ = ["build_parser", "expand_inputs", "main"]

# in the order of ``car-napari --help``
_COMMANDS = (_fit, _fit_texture, _synthesize, _retrieve, _segment, _mammo, _restore, _inpaint,
             _descratch)


def build_parser():
    """The ``car-napari`` argument parser, one sub-command per application.

    Returns
    -------
    parser : argparse.ArgumentParser
        Its parsed arguments carry the command's function as ``run``.

    Examples
    --------
    >>> args = build_parser().parse_args(["fit", "texture.png", "--order", "2"])
    >>> args.command, args.image, args.order
    ('fit', 'texture.png', 2)
    """
    parser = argparse.ArgumentParser(
        prog="car-napari",
        description="Haindl's causal autoregressive (CAR) random-field models, headless.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", required=True)
    for command in _COMMANDS:
        command.add_parser(sub)
    return parser


def _version():
    """The installed car-napari's version (the package's own when not installed)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("car-napari")
    except PackageNotFoundError:
        from .. import __version__

        return __version__


def main(argv=None):
    """Run the ``car-napari`` command.

    Parameters
    ----------
    argv : list of str, optional
        The arguments after the program name (default: ``sys.argv[1:]``).

    Returns
    -------
    status : int
        0 on success; for a batch, 1 when some inputs failed (each reported
        on one line, the others done); 2 when the inputs are wrong or none
        succeeded, or an optional dependency is missing (the reason, or what
        to install, is printed to stderr as ``car-napari: ...``).

    Raises
    ------
    SystemExit
        On a usage error or ``--help`` (from :mod:`argparse`, status 2 or 0).

    Examples
    --------
    >>> main(["fit", "no-such-file.png"])
    2
    """
    args = build_parser().parse_args(argv)
    try:
        with quiet_mode(getattr(args, "quiet", False)):
            return args.run(args) or 0
    except (BatchFailed, ImportError, *INPUT_ERRORS) as exc:  # ImportError: an extra missing
        print(f"car-napari: {exc}", file=sys.stderr)
        return 2
