"""The README's Python examples run: every ```python block, in order, in one namespace (a later
block may use what an earlier one made), from a temporary working directory."""

import re
import time
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
FENCE = re.compile(r"^```python[ \t]*\n(.*?)^```[ \t]*$", re.MULTILINE | re.DOTALL)


def _blocks(text):
    """``(first line number, source)`` of each ```python block of a Markdown text."""
    return [(text[: m.start(1)].count("\n") + 1, m.group(1)) for m in FENCE.finditer(text)]


BLOCKS = _blocks(README.read_text(encoding="utf-8"))


def test_the_blocks_are_found():
    assert BLOCKS, "README.md has no ```python block"
    assert _blocks("text\n```python\nx = 1\n```\n```bash\nls\n```\n```python\ny = x\n```\n") == [
        (3, "x = 1\n"), (9, "y = x\n")
    ]


@pytest.fixture(scope="module")
def namespace():
    """One namespace for all blocks (a failed block leaves what it made so far; the later
    blocks still run, so that each failure shows)."""
    return {"__name__": "__readme__"}


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    """The blocks' shared working directory (files one block saves, a later one loads)."""
    return tmp_path_factory.mktemp("readme")


@pytest.mark.parametrize("index", range(len(BLOCKS)),
                         ids=[f"line{line}" for line, _ in BLOCKS])
def test_readme_block(index, namespace, workdir, monkeypatch):
    monkeypatch.chdir(workdir)
    line, source = BLOCKS[index]
    # pad so that a traceback's line numbers are README.md's
    code = compile("\n" * (line - 1) + source, str(README), "exec")
    start = time.perf_counter()
    exec(code, namespace)
    print(f"README.md block at line {line}: {time.perf_counter() - start:.1f} s")
