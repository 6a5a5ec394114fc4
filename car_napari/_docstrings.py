"""Parameter sections shared by a job ``iter_<name>`` and its ``<name>``."""

from __future__ import annotations

import textwrap

_PLACEHOLDER = "    {parameters}"


def shared_parameters(parameters):
    """Decorator: put the numpydoc entries ``parameters`` at the docstring's
    ``{parameters}`` line (the two forms of one job take the same options)."""
    block = textwrap.indent(textwrap.dedent(parameters).strip("\n"), "    ")

    def decorate(func):
        if _PLACEHOLDER not in (func.__doc__ or ""):
            raise AssertionError(f"{func.__name__}'s docstring has no {_PLACEHOLDER!r} line")
        func.__doc__ = func.__doc__.replace(_PLACEHOLDER, block)
        return func

    return decorate
