"""The argparse pieces the commands share: argument types and the options
every command spells the same way."""

from __future__ import annotations

import argparse

import numpy as np


def add_cluster(parser, *, overwrite=True):
    """The --workers, --scheduler and (for commands that write a file per
    input) --overwrite options of a batch command."""
    parser.add_argument("--workers", type=positive_int, default=1,
                        help="worker processes on this machine (a dask LocalCluster when "
                             "more than 1; default 1: in this process)")
    parser.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help="submit to a running dask scheduler (e.g. tcp://host:8786)")
    if overwrite:
        parser.add_argument("--overwrite", action="store_true",
                            help="redo inputs whose outputs exist (default: skip them)")


def positive_int(text):
    """argparse type: an integer >= 1."""
    return _number(text, int, 1, "a positive integer")


def non_negative_int(text):
    """argparse type: an integer >= 0."""
    return _number(text, int, 0, "an integer >= 0")


def non_negative_float(text):
    """argparse type: a finite number >= 0."""
    return _number(text, float, 0.0, "a finite number >= 0")


def _number(text, kind, lowest, what):
    try:
        value = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be {what}; got {text!r}") from None
    if not np.isfinite(value) or value < lowest:
        raise argparse.ArgumentTypeError(f"must be {what}; got {text!r}")
    return value


def order_type(text):
    """argparse type for --order: 'auto' or a positive integer (the core's
    ``neighbourhood`` argument)."""
    if text == "auto":
        return text
    try:
        order = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"order must be 'auto' or a positive integer; got {text!r}") from None
    if order < 1:
        raise argparse.ArgumentTypeError(f"order must be 'auto' or a positive integer; got {order}")
    return order


def add_order(parser, help="neighbourhood order, or 'auto' for the decision rule (default)"):
    """The --order option."""
    parser.add_argument("--order", default="auto", type=order_type, help=help)


def add_inputs(parser, help, *, name="inputs",
               output="output folder; or, for a single input, the output file"):
    """The inputs (files, folders, globs) of a batch command, and its -o
    (``output``: its help)."""
    parser.add_argument(name, nargs="+", help=help)
    add_output(parser, output)


def add_output(parser, help):
    """The required -o/--output option."""
    parser.add_argument("-o", "--output", required=True, help=help)


def add_quiet(parser):
    """The --quiet option: nothing but errors (:func:`quiet_mode`)."""
    parser.add_argument("--quiet", action="store_true",
                        help="print nothing but errors (no progress, notes or per-image lines)")


def add_tile(parser, what):
    """The --tile option of a command that takes an image larger than memory
    (``what``: which input it applies to)."""
    parser.add_argument("--tile", type=positive_int, default=None,
                        help=f"{what}: side of a tile in pixels (default 2048)")


def add_batch_options(parser, run):
    """What every batch command ends with: --quiet, the cluster's options
    (:func:`add_cluster`), and ``run``, the function the command runs."""
    add_quiet(parser)
    add_cluster(parser)
    parser.set_defaults(run=run)
