"""documents_job: a job's docstring written from its plain form's (issue 33, docs written once)."""

import pytest

from car_napari._docstrings import documents_job


def _job_and_plain():
    def iter_double(x):
        """Double a number, as a job.

        {plain form}

        Yields
        ------
        Progress
            One record.

        Examples
        --------
        >>> 1
        1
        """

    @documents_job(iter_double)
    def double(x):
        """Double a number.

        Parameters
        ----------
        x : float
            The number.

        Returns
        -------
        float
            Twice ``x``.

        Raises
        ------
        TypeError
            If ``x`` is not a number.

        Examples
        --------
        >>> 2
        2
        """

    return iter_double, double


def test_the_job_gets_the_plain_forms_sections_in_numpydocs_order():
    job, plain = _job_and_plain()
    doc = job.__doc__
    lines = doc.splitlines()
    titles = [a for a, b in zip(lines, lines[1:], strict=False) if a and b == "-" * len(a)]
    assert titles == ["Parameters", "Returns", "Yields", "Raises", "See Also", "Examples"]
    assert doc.startswith("Double a number, as a job.\n\nThe generator form of :func:`double`")
    assert "x : float\n    The number." in doc and "Twice ``x``." in doc
    assert "double : The same without progress." in doc
    assert ">>> 1" in doc and ">>> 2" not in doc  # the job keeps its own examples
    assert "{plain form}" not in doc
    assert plain.__doc__.startswith("Double a number.\n")  # the plain form is left as it is


def test_a_job_without_the_placeholder_is_refused():
    def iter_f():
        """No placeholder."""

    def f():
        """Its plain form."""

    with pytest.raises(AssertionError, match="plain form"):
        documents_job(iter_f)(f)
