"""Write files so a reader sees either the old content or the new, never half of one; and a
study's level runs and report together or not at all."""

from __future__ import annotations

import errno
import json
import os
import re
import shutil
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


# What a study owns in its scene directory besides the level runs.
REPORT_FILES = ("convergence.csv", "summary.json", "convergence.png")
LEVEL_DIR = re.compile(r"n\d+")
BACKUP_PREFIX = ".backup-"


class StudyTransaction:
    """A study's writes to its scene directory, all or nothing.

    On entry the earlier study (its level dirs and report) is kept as hard links in a hidden
    backup dir: nothing under a level dir is ever changed in place (a new run is swapped in
    whole, run.py), so the links hold the earlier files at no copying cost. On success the
    backup goes; on any failure or signal the earlier level dirs and report are put back, so
    the directory holds the earlier complete study or the new one, never a mix. A backup
    left by a harness that was SIGKILLed is restored on the next entry."""

    def __init__(self, case_dir: Path) -> None:
        self.case_dir = case_dir
        self.backup = case_dir / f"{BACKUP_PREFIX}{os.getpid()}-{uuid.uuid4().hex[:8]}"

    def __enter__(self) -> StudyTransaction:
        if not self.case_dir.is_dir():
            return self
        for stale in self.case_dir.glob(f"{BACKUP_PREFIX}*"):
            if not pid_alive(backup_pid(stale)):
                restore(stale, self.case_dir)
        self.backup.mkdir()
        for item in study_items(self.case_dir):
            if item.is_dir():
                shutil.copytree(item, self.backup / item.name, copy_function=link_or_copy)
            else:
                link_or_copy(item, self.backup / item.name)
        return self

    def __exit__(self, kind: type | None, *_: object) -> None:
        if not self.backup.exists():
            return
        if kind is not None:
            restore(self.backup, self.case_dir)
        shutil.rmtree(self.backup, ignore_errors=True)


def link_or_copy(source: str | Path, target: str | Path) -> None:
    """A hard link (no data copied); a copy where the file system has none."""
    try:
        os.link(source, target)
    except OSError as exc:
        if exc.errno not in (errno.EPERM, errno.EXDEV, errno.EOPNOTSUPP, errno.EMLINK):
            raise
        shutil.copy2(source, target)


def study_items(case_dir: Path) -> list[Path]:
    return [p for p in sorted(case_dir.iterdir())
            if (p.is_dir() and LEVEL_DIR.fullmatch(p.name)) or (p.is_file() and p.name in REPORT_FILES)]


def restore(backup: Path, case_dir: Path) -> None:
    """Put every item of `backup` back in place of what is there now, then drop the backup."""
    for item in sorted(backup.iterdir()):
        target = case_dir / item.name
        if item.is_dir():
            old = case_dir / f".old-{item.name}-{uuid.uuid4().hex[:8]}"
            if target.exists():
                os.replace(target, old)
            os.replace(item, target)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(item, target)
    shutil.rmtree(backup, ignore_errors=True)


def backup_pid(backup: Path) -> int:
    try:
        return int(backup.name[len(BACKUP_PREFIX):].split("-")[0])
    except ValueError:
        return 0


def pid_alive(pid: int) -> bool:
    if pid <= 0:
        return False
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def mixed_levels(case_dir: Path) -> list[int]:
    """Levels whose run is not the one summary.json was written with (its recorded key):
    empty for a consistent study."""
    try:
        runs = json.loads((case_dir / "summary.json").read_text()).get("runs", {})
    except (OSError, ValueError):
        return []
    out = []
    for n, facts in runs.items():
        try:
            key = json.loads((case_dir / f"n{n}" / "inputs.json").read_text()).get("key")
        except (OSError, ValueError):
            key = None
        if facts.get("key") != key:
            out.append(int(n))
    return sorted(out)
