"""Parameter sections shared by a job ``iter_<name>`` and its ``<name>``."""

from __future__ import annotations

import re
import textwrap

# the placeholder line, at the indentation of the docstring it stands in
# (4 spaces in a function's, 8 in a method's)
_PLACEHOLDER = re.compile(r"^([ \t]*)\{parameters\}$", re.MULTILINE)


def shared_parameters(parameters):
    """Decorator: put the numpydoc entries ``parameters`` at the docstring's
    ``{parameters}`` line, indented as that line is (the two forms of one
    job take the same options; a method's docstring works as a function's)."""
    block = textwrap.dedent(parameters).strip("\n")

    def decorate(func):
        doc = func.__doc__ or ""
        found = _PLACEHOLDER.search(doc)
        if found is None:
            raise AssertionError(f"{func.__name__}'s docstring has no '{{parameters}}' line")
        indented = textwrap.indent(block, found.group(1))
        func.__doc__ = doc[:found.start()] + indented + doc[found.end():]
        return func

    return decorate
