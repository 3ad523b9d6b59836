"""The README's code blocks, read from README.md itself, so that the tests run exactly what it says."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from .blender import fresh_process

README = Path(__file__).resolve().parent.parent / "README.md"
#: The README's commands run from a clone holding the venv in `.venv`; the tests use this one's.
VENV_BIN = ".venv/bin/"


@dataclass(frozen=True)
class Block:
    """One fenced code block: the section it is in (its ``## `` title), its language, its place among
    that section's blocks of the same language, and its code."""

    section: str
    language: str
    index: int
    code: str

    @property
    def key(self) -> tuple[str, str, int]:
        return self.section, self.language, self.index

    def lines(self) -> list[str]:
        return [line for line in self.code.splitlines() if line.strip()]


def blocks(text: str | None = None) -> list[Block]:
    """Every fenced block of the README, in order."""
    text = README.read_text(encoding="utf-8") if text is None else text
    found, counts, section = [], {}, ""
    for match in re.finditer(r"^## ([^\n]+)$|^```(\w+)\n(.*?)^```$", text, re.MULTILINE | re.DOTALL):
        if match[1]:
            section = match[1].strip()
            continue
        key = (section, match[2])
        found.append(Block(section, match[2], counts.get(key, 0), match[3]))
        counts[key] = counts.get(key, 0) + 1
    return found


def block(section: str, language: str, index: int = 0) -> Block:
    (found,) = [b for b in blocks() if b.key == (section, language, index)]
    return found


def command(line: str) -> list[str]:
    """A README shell line as arguments, its trailing comment dropped and ``.venv/bin/`` this venv's."""
    words = shlex.split(line, comments=True)
    bin_dir = str(Path(sys.executable).parent) + os.sep
    return [bin_dir + w[len(VENV_BIN) :] if w.startswith(VENV_BIN) else w for w in words]


def run_python(code: str, cwd: Path, user_dir: Path, timeout: float = 1800) -> subprocess.CompletedProcess:
    """A README Python block saved as a script and run as one (``python script.py``), as a reader would."""
    script = cwd / "readme_snippet.py"
    script.write_text(code, encoding="utf-8")
    return fresh_process([sys.executable, str(script)], user_dir=user_dir, cwd=cwd, timeout=timeout)
