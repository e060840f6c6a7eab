"""Write files so a reader sees either the old content or the new, never half of one."""

from __future__ import annotations

import os
import uuid
from pathlib import Path


def sibling_temp(target: Path) -> Path:
    """A unique hidden name next to `target` (same filesystem, so os.replace is atomic)."""
    return target.with_name(f".{target.name}.{os.getpid()}-{uuid.uuid4().hex[:8]}.tmp")


def write_atomic(target: Path, content: str | bytes) -> None:
    tmp = sibling_temp(target)
    try:
        if isinstance(content, bytes):
            tmp.write_bytes(content)
        else:
            tmp.write_text(content)
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)
