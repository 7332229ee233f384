"""The README's Python blocks run as written (from the repository root, as a new user would).

A block preceded by `<!-- readme-test: skip, <reason> -->` is skipped (those needing a
licensed SMPL file); the README says so next to it.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
FENCE = re.compile(r"(?:<!--\s*readme-test:\s*skip,?\s*([^>]*?)\s*-->\s*\n)?```python\n(.*?)```", re.S)


def _blocks():
    text = (REPO / "README.md").read_text()
    out = []
    for i, m in enumerate(FENCE.finditer(text)):
        line = text[: m.start(2)].count("\n") + 1
        marks = [pytest.mark.skip(reason=m.group(1) or "marked in the README")] if m.group(0).startswith("<!--") else []
        out.append(pytest.param(m.group(2), line, id=f"block{i}-line{line}", marks=marks))
    return out


BLOCKS = _blocks()


def test_readme_has_runnable_blocks():
    assert sum(1 for b in BLOCKS if not b.marks) >= 2


@pytest.mark.parametrize("code, line", BLOCKS)
def test_readme_block(code, line, monkeypatch):
    if "../shared/data/cmu" in code and not (REPO.parent / "shared" / "data" / "cmu").is_dir():
        pytest.skip("the CMU clips are not beside this checkout")
    monkeypatch.chdir(REPO)  # the README's paths are relative to the repository root
    # dont_inherit: the block runs without this file's `from __future__ import annotations`, as a
    # user's script would (postponed annotations break a dataclass defined in an exec'd block).
    exec(compile(code, f"README.md, block at line {line}", "exec", dont_inherit=True), {"__name__": "__readme__"})
