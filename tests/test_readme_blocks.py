"""The README's Python blocks work when pasted into a script (issue 43): each prints what it
computes (a bare expression at the end of a block shows in a notebook, not in a script, which
printed nothing for minutes), and they run, in order, as one session."""

from __future__ import annotations

import ast
import contextlib
import io
import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def python_blocks() -> list[str]:
    """The README's ```python blocks, in order."""
    return re.findall(r"```python\n(.*?)```", README.read_text(), re.S)


def _bare(block: str) -> list[str]:
    """The statements of ``block`` whose value a script throws away: expressions that are not
    a call (a call of print included; other calls are kept as work done for their effect)."""
    return [
        ast.unparse(node)
        for node in ast.parse(block).body
        if isinstance(node, ast.Expr) and not isinstance(node.value, ast.Call)
    ]


def test_every_block_prints_what_it_computes():
    """No block holds a bare expression, and each prints something."""
    blocks = python_blocks()
    assert len(blocks) >= 6
    for k, block in enumerate(blocks):
        assert _bare(block) == [], f"README python block {k}"
        calls = [n.func.id for n in ast.walk(ast.parse(block)) if isinstance(n, ast.Call)
                 and isinstance(n.func, ast.Name)]  # fmt: skip
        assert "print" in calls, f"README python block {k} prints nothing"


def _run(blocks: list[str]) -> list[str]:
    """Run ``blocks`` in one namespace, in order; what each printed."""
    namespace: dict = {}
    printed = []
    for k, block in enumerate(blocks):
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            exec(compile(block, f"README block {k}", "exec"), namespace)
        printed.append(out.getvalue())
    return printed


def test_the_first_block_prints_the_room():
    """The first block (a room from echoes, 3 s) prints the verdict, the loudspeaker and the
    room's volume, the true shoebox's 49.06 m^3 within 0.1 m^3."""
    (text,) = _run(python_blocks()[:1])
    lines = text.splitlines()
    assert lines[0].startswith("True ")
    assert float(lines[-1]) == pytest.approx(5.1 * 3.7 * 2.6, abs=0.1)


@pytest.mark.slow
def test_every_block_runs_and_prints(dechorate_dir):
    """Every block, in order, as one pasted script (dEchorate and Plaza data; 1.5-3 min on two
    cores, most of it the 30 x 14 dEchorate calibration): each prints something."""
    printed = _run(python_blocks())
    assert all(text.strip() for text in printed)
