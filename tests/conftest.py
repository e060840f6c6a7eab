"""Shared fixtures for the harness's own tests: the paper case and a stand-in solver."""

from __future__ import annotations

from pathlib import Path

import pytest

from harness.core.layout import Layout

DATA = Path(__file__).parent / "data"


@pytest.fixture
def paper_case() -> Path:
    return DATA / "paper.toml"


@pytest.fixture
def stub_layout(tmp_path: Path) -> Layout:
    """Results in a temp dir, solved by tests/data/stub_freefem (interface only, no physics)."""
    return Layout(results=tmp_path / "results", freefem=DATA / "stub_freefem")
