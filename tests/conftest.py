"""Shared test helpers: a copy of a catalogue arm folder to break in a test."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

import robots


@pytest.fixture
def arm_copy(tmp_path: Path) -> Callable[..., Path]:
    """Copy catalogue arm ``name`` into tmp_path, applying (old, new) text edits to its files."""

    def make(name: str, toml_edits: list[tuple[str, str]] = (), urdf_edits: list[tuple[str, str]] = (),
             as_name: str | None = None) -> Path:
        dst = tmp_path / (as_name or name)
        shutil.copytree(robots.CATALOGUE_DIR / name, dst)
        for fname, edits in (("robot.toml", toml_edits), ("robot.urdf", urdf_edits)):
            text = (dst / fname).read_text()
            for old, new in edits:
                assert old in text, f"test edit not applicable: {old!r} not in {fname}"
                text = text.replace(old, new, 1)
            (dst / fname).write_text(text)
        return dst

    return make
