"""Find a FreeFEM rank that has died while its MPI launcher lives on.

An MPI launcher is meant to end every rank when one dies; Open MPI's mpiexec does so within
a second or two, but under load it has been seen to hang with the dead rank left a zombie
(never reaped) and the others blocked in a collective call, until the run's timeout. The
harness therefore looks for such a rank itself while it waits (freefem.wait_measured): a
FreeFEM process under the launcher that has ended but is still a zombie for a few seconds is
a dead rank, and its wait status (field 52 of /proc/<pid>/stat, Linux >= 3.5) says how it
ended.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

PROC = Path("/proc")
# /proc/<pid>/stat's fields after "pid (comm) ": state is field 3, ppid 4, exit_code 52.
STATE, PPID, EXIT_CODE = 0, 1, 49


@dataclass(frozen=True)
class DeadRank:
    pid: int
    status: int  # the wait status the launcher has not collected

    @property
    def returncode(self) -> int:
        """As a shell or a launcher reports it: 128 + the signal, else the rank's exit code."""
        if os.WIFSIGNALED(self.status):
            return 128 + os.WTERMSIG(self.status)
        return os.WEXITSTATUS(self.status)


def _table() -> dict[int, tuple[str, list[str]]]:
    """Every process: its command name and its stat fields after the name."""
    table: dict[int, tuple[str, list[str]]] = {}
    for entry in PROC.iterdir():
        if not entry.name.isdigit():
            continue
        try:
            text = (entry / "stat").read_text()
        except OSError:  # ended meanwhile
            continue
        close = text.rfind(")")
        table[int(entry.name)] = (text[text.find("(") + 1:close], text[close + 2:].split())
    return table


def dead_rank(launcher: int, program: str = "FreeFem++") -> DeadRank | None:
    """A process named `program`* under `launcher` (not the launcher itself) that has ended and
    is not reaped; None when every one is alive or gone."""
    table = _table()
    children: dict[int, list[int]] = {}
    for pid, (_, fields) in table.items():
        children.setdefault(int(fields[PPID]), []).append(pid)
    stack = list(children.get(launcher, []))
    while stack:
        pid = stack.pop()
        name, fields = table[pid]
        if fields[STATE] == "Z" and name.startswith(program) and len(fields) > EXIT_CODE:
            return DeadRank(pid, int(fields[EXIT_CODE]))
        stack += children.get(pid, [])
    return None
