"""Docstring sections shared by a job ``iter_<name>`` and its ``<name>``.

The two forms of one job take the same options, raise the same errors and
start their examples from the same image: those sections are written once,
as module constants, and put into each docstring at a ``{name}`` line (the
line holds only the placeholder, indented like the text it stands for); or the
job's documentation is written from its plain form's (:func:`documents_job`).
"""

from __future__ import annotations

import inspect
import re
import textwrap


def shared_sections(**sections):
    """Decorator: put each text of ``sections`` at the docstring's ``{name}``
    lines, indented as each line is (a method's docstring works as a
    function's); every placeholder given must be there. A section's text
    carries its header, but for ``parameters``: the numpydoc entries alone
    get the "Parameters" header put before them."""
    blocks = {name: textwrap.dedent(text).strip("\n") for name, text in sections.items()}
    if "parameters" in blocks and not blocks["parameters"].startswith("Parameters\n"):
        blocks["parameters"] = "Parameters\n----------\n" + blocks["parameters"]

    def decorate(func):
        doc = func.__doc__ or ""
        for name, block in blocks.items():
            line = re.compile(r"^([ \t]*)\{" + re.escape(name) + r"\}$", re.MULTILINE)
            if line.search(doc) is None:
                raise AssertionError(f"{func.__name__}'s docstring has no '{{{name}}}' line")
            doc = line.sub(lambda found, block=block: textwrap.indent(block, found.group(1)),
                           doc)
        func.__doc__ = doc
        return func

    return decorate


def raises_as(function, *errors):
    """A Raises section that sends the reader to ``function`` for each of
    ``errors`` (a job raises what its plain form raises), for
    :func:`shared_sections`."""
    return "Raises\n------\n" + "".join(f"{error}\n    As :func:`{function}`.\n"
                                         for error in errors)


def constructor_sections(cls, function, errors=("ValueError", "TypeError")):
    """The Returns, Raises and See Also sections of a model's constructor
    ``cls.fit`` that is the same as the function ``function``, for
    :func:`shared_sections`."""
    return (f"Returns\n-------\n{cls}\n    The fitted model.\n\n" + raises_as(function, *errors)
            + f"\nSee Also\n--------\n{function} : The same, as a function.\n")


def shared_parameters(parameters):
    """Decorator: put the Parameters section of the numpydoc entries
    ``parameters`` at the docstring's ``{parameters}`` line."""
    return shared_sections(parameters=parameters)


_JOB_PLACEHOLDER = "{plain form}"
_HEADER = re.compile(r"^(\w[\w ]*)\n-+\n", re.MULTILINE)


def _sections(doc):
    """``{section title: its text, header included}`` of a cleaned numpydoc
    docstring, and the text before the first section."""
    heads = list(_HEADER.finditer(doc))
    ends = [h.start() for h in heads[1:]] + [len(doc)]
    sections = {h.group(1): doc[h.start() : end].rstrip("\n") + "\n"
                for h, end in zip(heads, ends, strict=True)}
    return doc[: heads[0].start() if heads else len(doc)], sections


_ORDER = ("Parameters", "Returns", "Yields", "Receives", "Other Parameters", "Raises", "Warns",
          "Warnings", "See Also", "Notes", "References", "Examples")


def _with_section(sections, title, text):
    """``sections`` (in numpydoc's order) with ``title: text`` in its place."""
    items = list(sections.items())
    rank = _ORDER.index(title)
    at = next((k for k, (t, _) in enumerate(items) if t in _ORDER and _ORDER.index(t) > rank),
              len(items))
    return dict(items[:at] + [(title, text)] + items[at:])


def documents_job(job):
    """Decorator for a plain form ``<name>``: write its job ``iter_<name>``'s
    documentation from its own (documentation written once).

    The job's docstring holds its summary, a ``{plain form}`` line, then its
    own sections (Yields, See Also, Examples). That line becomes a sentence
    naming the plain form with the plain form's Parameters and Returns; the
    plain form's Raises and Warns go after the job's Yields, and a See Also
    naming the plain form is added when the job has none.
    """

    def decorate(plain):
        job_doc, plain_doc = inspect.cleandoc(job.__doc__), inspect.cleandoc(plain.__doc__)
        if _JOB_PLACEHOLDER not in job_doc:
            raise AssertionError(f"{job.__name__}'s docstring has no {_JOB_PLACEHOLDER!r} line")
        _, shared = _sections(plain_doc)
        opening = textwrap.fill(
            f"The generator form of :func:`{plain.__name__}`: the same parameters, result and "
            "errors (raised when the generator is first advanced).", 72) + "\n\n" + "\n".join(
            shared[s] for s in ("Parameters", "Returns") if s in shared)
        head, own = _sections(job_doc.replace(_JOB_PLACEHOLDER, opening.rstrip("\n")))
        shared["See Also"] = f"See Also\n--------\n{plain.__name__} : The same without progress.\n"
        for title in ("Raises", "Warns", "See Also"):
            if title in shared and title not in own:
                own = _with_section(own, title, shared[title])
        job.__doc__ = head + "\n".join(own.values())
        return plain

    return decorate
