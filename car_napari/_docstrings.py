"""Docstring sections shared by a job ``iter_<name>`` and its ``<name>``.

The two forms of one job take the same options, raise the same errors and
start their examples from the same image: those sections are written once,
as module constants, and put into each docstring at a ``{name}`` line (the
line holds only the placeholder, indented like a section's body).
"""

from __future__ import annotations

import textwrap


def shared_sections(**sections):
    """Decorator: put each text of ``sections`` at the docstring's
    ``    {name}`` line (every placeholder given must be there)."""
    blocks = {name: textwrap.indent(textwrap.dedent(text).strip("\n"), "    ")
              for name, text in sections.items()}

    def decorate(func):
        doc = func.__doc__ or ""
        for name, block in blocks.items():
            placeholder = "    {" + name + "}"
            if placeholder not in doc:
                raise AssertionError(f"{func.__name__}'s docstring has no {placeholder!r} line")
            doc = doc.replace(placeholder, block)
        func.__doc__ = doc
        return func

    return decorate


def shared_parameters(parameters):
    """Decorator: put the numpydoc entries ``parameters`` at the docstring's
    ``{parameters}`` line."""
    return shared_sections(parameters=parameters)
