"""Write files so a reader sees either the old content or the new, never half of one; and a
study's level runs and report together or not at all, by one study at a time."""

from __future__ import annotations

import errno
import json
import os
import re
import shutil
import uuid
from pathlib import Path
from typing import Collection

from harness.core.signals import CHILDREN
from harness.core.study_lock import DirectoryLocks

from harness.core.faults import naming


def sibling_temp(target: Path) -> Path:
    """A unique hidden name next to `target` (same filesystem, so os.replace is atomic)."""
    return target.with_name(f".{target.name}.{os.getpid()}-{uuid.uuid4().hex[:8]}.tmp")


def write_atomic(target: Path, content: str | bytes) -> None:
    tmp = sibling_temp(target)
    try:
        with naming(target):
            if isinstance(content, bytes):
                tmp.write_bytes(content)
            else:
                tmp.write_text(content)
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)


# How a study owns a directory (StudyTransaction): a scene directory's level dirs and
# REPORT_FILES, an output directory's level dirs and files, or all of it.
SCENE, OUTPUT, WHOLE = "scene", "output", "whole"
# What a study owns in its scene directory besides the level runs.
REPORT_FILES = ("convergence.csv", "summary.json", "convergence.png", "gci.csv", "quantities.csv", "quantities.png")
LEVEL_DIR = re.compile(r"n\d+")
BACKUP_PREFIX = ".backup-"
# A level's run in progress (run.py: swapped in whole when it succeeds), and a level dir
# being replaced by one (swap_in, restore): left behind only by a process that died.
RUN_TEMP_PREFIX = ".tmp-"
OLD_PREFIX = ".old-"
# Not backed up inside a directory: what only a live or dead process owns (the sweep's).
TRANSIENT = shutil.ignore_patterns(f"{RUN_TEMP_PREFIX}*", f"{OLD_PREFIX}*", f"{BACKUP_PREFIX}*")


class StudyTransaction:
    """A study's writes to the directories it owns, all or nothing.

    `directories`: each scene directory of the study (its level dirs and REPORT_FILES), each
    output directory (`outputs`: its level dirs and every file directly in it: the study's
    tables, Markdown and plots) and each directory the study owns whole (`whole`: everything
    visible in it, its sub-folders and meshes too, but the directories owned here in their
    own right: an adaptive study's folder, whose meshes are made from its runs). On entry what
    they hold is kept as hard links in a hidden backup dir per directory: nothing under a
    level dir is ever changed in place (a new run is swapped in whole, run.py), and every file
    is written to a temp name then moved over its own, so the links hold the earlier files at
    no copying cost. On success the backups go; on any failure or signal every directory's
    earlier items are put back, so each holds the earlier complete study or the new one, never
    a mix. What the earlier study did not have stays: a new level's run (the cache of the
    next study) and a failed run's `.failed` dir (what the error line points to).

    One study at a time: every directory it owns, and each of `locked` (where its runs write
    without a report of its own: `solve`'s scene), is locked on entry (study_lock.py), or a
    StudyBusy (exit 7) before anything is touched. Holding the locks, whatever a dead
    process left there is stale: a backup is restored, a run's temp dir and a half-swapped
    level dir are removed, quietly. The temp dirs found on a successful exit are
    those of runs whose process died during the study, a Dask worker killed while its task
    was rerun elsewhere (`swept_after`, for the study to report)."""

    def __init__(self, *directories: Path, outputs: tuple[Path, ...] = (), locked: tuple[Path, ...] = (),
                 whole: tuple[Path, ...] = ()) -> None:
        tag = f"{BACKUP_PREFIX}{os.getpid()}-{uuid.uuid4().hex[:8]}"
        # A directory listed twice is owned the widest way: whole, then as an output (all its files).
        owned = ({Path(d): SCENE for d in directories} | {Path(d): OUTPUT for d in outputs}
                 | {Path(d): WHOLE for d in whole})
        self.owned = [(directory, kind, directory / tag) for directory, kind in owned.items()]
        self.watched = tuple(dict.fromkeys([*owned, *map(Path, locked)]))
        self.locks = DirectoryLocks(self.watched)
        self.swept_after: list[Path] = []

    @property
    def backup(self) -> Path:
        """The first directory's backup (one directory: the study's one scene)."""
        return self.owned[0][2]

    def __enter__(self) -> StudyTransaction:
        self.locks.__enter__()
        try:
            for directory, kind, backup in self.owned:
                for stale in sorted(directory.glob(f"{BACKUP_PREFIX}*")):  # the lock's: a dead study's
                    restore(stale, directory)
            for directory in self.watched:
                sweep(directory)
            owned = {directory for directory, _kind, _backup in self.owned}
            for directory, kind, backup in self.owned:
                backup.mkdir()
                for item in study_items(directory, kind, skip=owned):
                    if item.is_dir():
                        shutil.copytree(item, backup / item.name, copy_function=link_or_copy, ignore=TRANSIENT)
                    else:
                        link_or_copy(item, backup / item.name)
        except BaseException:
            self.__exit__(RuntimeError)
            raise
        return self

    def __exit__(self, kind: type | None, *_: object) -> None:
        try:
            for directory, _owned, backup in self.owned:
                if not backup.exists():
                    continue
                if kind is not None:
                    restore(backup, directory)
                shutil.rmtree(backup, ignore_errors=True)
            live = CHILDREN.live_dirs()  # this process's runs still being torn down
            self.swept_after = [p for directory in self.watched for p in sweep(directory, keep=live)]
        finally:
            self.locks.release()


def link_or_copy(source: str | Path, target: str | Path) -> None:
    """A hard link (no data copied); a copy where the file system has none."""
    try:
        os.link(source, target)
    except OSError as exc:
        if exc.errno not in (errno.EPERM, errno.EXDEV, errno.EOPNOTSUPP, errno.EMLINK):
            raise
        shutil.copy2(source, target)


def study_items(case_dir: Path, kind: str = SCENE, skip: Collection[Path] = ()) -> list[Path]:
    """What a study owns in a directory: a scene directory's level dirs and report files, an
    output directory's level dirs and every visible file, or everything visible but `skip`
    (the sub-folders the study owns in their own right) and failed runs' dirs."""
    if kind == WHOLE:
        return [p for p in visible(case_dir) if p not in skip and not p.name.endswith(".failed")]
    return [p for p in sorted(case_dir.iterdir())
            if (p.is_dir() and LEVEL_DIR.fullmatch(p.name))
            or (p.is_file() and (p.name in REPORT_FILES or (kind == OUTPUT and not p.name.startswith("."))))]


def visible(directory: Path) -> list[Path]:
    """Every item of `directory` but the hidden ones (its lock, backups, runs' temp dirs)."""
    return [p for p in sorted(directory.iterdir()) if not p.name.startswith(".")]


def restore(backup: Path, case_dir: Path) -> None:
    """Put every item of `backup` back in place of what is there now, then drop the backup."""
    for item in sorted(backup.iterdir()):
        target = case_dir / item.name
        if item.is_dir():
            old = case_dir / f"{OLD_PREFIX}{item.name}-{uuid.uuid4().hex[:8]}"
            if target.exists():
                os.replace(target, old)
            os.replace(item, target)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(item, target)
    shutil.rmtree(backup, ignore_errors=True)


def sweep(directory: Path, keep: Collection[Path] = ()) -> list[Path]:
    """Remove the runs' temp dirs and half-swapped level dirs in `directory` (but `keep`'s):
    called only under the directory's lock, when no live run of another study can own one."""
    if not directory.is_dir():
        return []
    stale = [p for prefix in (RUN_TEMP_PREFIX, OLD_PREFIX) for p in sorted(directory.glob(f"{prefix}*"))
             if p not in keep]
    for path in stale:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
    return stale


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
