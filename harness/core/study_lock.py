"""One writer per study directory: an exclusive flock(2) on `<directory>/.lock`, taken
without waiting. The kernel drops the lock when its holder ends, however it ends (kill -9
too), so a dead study never blocks the next; the file names the holder for the refusal's
one line."""

from __future__ import annotations

import contextlib
import fcntl
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

from harness.core.errors import StudyBusy

LOCK_NAME = ".lock"


@dataclass
class HeldLock:
    directory: Path
    fd: int
    created: tuple[Path, ...]  # it and the parents this lock made: removed again if left empty


@dataclass
class DirectoryLocks:
    """Every directory of `directories` locked on entry (each created if missing), or a
    StudyBusy naming the first one another live process holds, with nothing left locked."""

    directories: tuple[Path, ...]
    held: list[HeldLock] = field(default_factory=list)

    def __enter__(self) -> DirectoryLocks:
        try:
            # One lock per directory however it is spelled: a second flock of the same file
            # from this process would be refused as another study's.
            for directory in sorted({Path(d).resolve() for d in self.directories}):
                self.held.append(lock(directory))
        except BaseException:
            self.release()
            raise
        return self

    def __exit__(self, *_: object) -> None:
        self.release()

    def release(self) -> None:
        while self.held:
            unlock(self.held.pop())


def lock(directory: Path) -> HeldLock:
    created = tuple(d for d in [directory, *directory.parents] if not d.exists())
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / LOCK_NAME
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = holder_of(fd)
            os.close(fd)
            raise StudyBusy(f"{directory} is being written by another study ({holder}): wait for it to end, "
                            f"or give another --results") from None
        except BaseException:
            os.close(fd)
            raise
        # A holder that removed the file (and its empty directory) on release, after this
        # process opened it: the lock is on a file no one else will find, so take it again.
        with contextlib.suppress(FileNotFoundError):
            if os.fstat(fd).st_ino == os.stat(path).st_ino:
                break
        os.close(fd)
        directory.mkdir(parents=True, exist_ok=True)
    os.ftruncate(fd, 0)
    os.write(fd, f"pid {os.getpid()}: {' '.join(sys.argv[1:])[:200]}\n".encode())
    return HeldLock(directory, fd, created)


def unlock(held: HeldLock) -> None:
    try:
        if held.created:  # a study that wrote nothing leaves no directory behind
            with contextlib.suppress(OSError):
                if [p.name for p in held.directory.iterdir()] == [LOCK_NAME]:
                    (held.directory / LOCK_NAME).unlink()
                    for made in held.created:  # innermost first; stops at one that holds anything
                        made.rmdir()
    finally:
        fcntl.flock(held.fd, fcntl.LOCK_UN)
        os.close(held.fd)


def holder_of(fd: int) -> str:
    """What the holder wrote into the lock file ("pid N: its command line")."""
    with contextlib.suppress(OSError):
        text = os.pread(fd, 512, 0).decode(errors="replace").strip()
        if text:
            return text
    return "pid unknown"
