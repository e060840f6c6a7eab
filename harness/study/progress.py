"""Progress of a long level while it runs: each Newton step as FreeFEM prints it, and the CPU
time and memory its process holds, as lines of the study's progress sink; a short level says
only its `done` line."""

from __future__ import annotations

import contextlib
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

Progress = Callable[[str], None]

# freefem/newton.idp's line for each finished step ("newton 3 |R| ... linear its 7").
STEP_PREFIX = "newton "


@dataclass(frozen=True)
class Pace:
    """When a running level speaks. `after_s`: silent before (3D h = 1/16 takes ~20 s, 1/32
    ~2 min, 1/64 ~15 min on this machine: only the last two speak); `every_s`: a line at
    least this often while no Newton step ends (1/64's assembly and first step take minutes);
    `poll_s`: how often the file and the process are read."""

    after_s: float = 60.0
    every_s: float = 120.0
    poll_s: float = 2.0


@dataclass(frozen=True)
class Usage:
    """A process's CPU seconds (user + system) and resident memory now and at its peak, MiB."""

    cpu_s: float
    rss_mib: float
    peak_mib: float

    def __str__(self) -> str:
        return f"FreeFEM CPU {self.cpu_s:.1f} s, {self.rss_mib / 1024:.2f} GiB resident (peak {self.peak_mib / 1024:.2f})"


def usage_of(pid: int) -> Usage | None:
    """/proc's view of a live process (Linux); None once it has exited or where /proc is not."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        status = Path(f"/proc/{pid}/status").read_text().splitlines()
    except (OSError, IndexError):
        return None
    # stat's fields after the command name: utime and stime are the 12th and 13th (proc(5)).
    cpu = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    kib = {line.split(":")[0]: float(line.split()[1]) for line in status if line.startswith(("VmRSS:", "VmHWM:"))}
    if "VmRSS" not in kib:  # a process that has exited and is not yet reaped holds no memory to report
        return None
    return Usage(cpu, kib["VmRSS"] / 1024, kib.get("VmHWM", kib["VmRSS"]) / 1024)


class NewLines:
    """The complete lines appended to a file since the last read (a line still being written
    waits for its end)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._offset = 0
        self._partial = b""

    def read(self) -> list[str]:
        try:
            with open(self.path, "rb") as f:
                f.seek(self._offset)
                data = f.read()
        except OSError:
            return []
        self._offset += len(data)
        *lines, self._partial = (self._partial + data).split(b"\n")
        return [line.decode(errors="replace").strip() for line in lines]


@contextlib.contextmanager
def watching(stdout: Path | None, pid: int | None, label: str, progress: Progress,
             pace: Pace = Pace()) -> Iterator[None]:
    """While the body runs (a wait for the level's FreeFEM), a thread echoes the Newton steps
    of `stdout` (its stdout.txt) and the process's usage, once the wait has lasted `after_s`;
    on leaving, the steps not yet said are said (a level that spoke finishes its story)."""
    if stdout is None:
        yield
        return
    lines, stop, began = NewLines(stdout), threading.Event(), time.monotonic()
    said = {"last": began, "spoke": False}

    def say(text: str) -> None:
        usage = usage_of(pid) if pid is not None else None
        minutes = (time.monotonic() - began) / 60
        progress(f"{label} running {minutes:.1f} min" + (f" ({usage})" if usage else "") + f": {text}")
        said.update(last=time.monotonic(), spoke=True)

    def echo(steps: list[str]) -> None:
        for step in steps:
            say(step)

    def watch() -> None:
        pending: list[str] = []
        last_step = "before the first Newton step"
        while not stop.wait(pace.poll_s):
            pending += [line for line in lines.read() if line.startswith(STEP_PREFIX)]
            now = time.monotonic()
            if now - began < pace.after_s:
                continue
            if pending:
                last_step = f"after {pending[-1].split('|')[0].strip()}"
                echo(pending)
                pending = []
            elif now - said["last"] >= pace.every_s:
                say(f"still working, {last_step}")
        if said["spoke"]:
            echo(pending + [line for line in lines.read() if line.startswith(STEP_PREFIX)])

    thread = threading.Thread(target=watch, name=f"progress {label}", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()
