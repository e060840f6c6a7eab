"""A long level says how it goes while it runs (harness/study/progress.py): each Newton step
FreeFEM prints, with its process's CPU time and memory; a short level says nothing but its
`done` line."""

from __future__ import annotations

import functools
import os
import threading
import time
from pathlib import Path

from harness.core.layout import Layout
from harness.scene.scene import load_scene
from harness.study import engine
from harness.study.engine import InlineMeshes, run_levels
from harness.study.progress import NewLines, Pace, usage_of, watching

CASES = Path(__file__).resolve().parents[1] / "cases"
EAGER = Pace(after_s=0.0, every_s=0.05, poll_s=0.01)


def test_only_complete_lines_are_read_and_each_once(tmp_path):
    path = tmp_path / "stdout.txt"
    lines = NewLines(path)
    assert lines.read() == []  # not written yet
    path.write_bytes(b"bulk: assembled\nnewton 1 |R| 1e-3")
    assert lines.read() == ["bulk: assembled"]
    with open(path, "ab") as f:
        f.write(b" alpha 1\nnewton 2 |R| 1e-9\n")
    assert lines.read() == ["newton 1 |R| 1e-3 alpha 1", "newton 2 |R| 1e-9"]
    assert lines.read() == []


def test_the_usage_of_this_process_is_read_from_proc():
    usage = usage_of(os.getpid())
    assert usage is not None and usage.cpu_s > 0 and 0 < usage.rss_mib <= usage.peak_mib
    assert usage_of(2**22 + 1) is None  # above Linux's largest pid: no such process


def test_a_long_wait_says_every_step_with_the_usage_and_keeps_saying_it_works(tmp_path):
    path, said = tmp_path / "stdout.txt", []
    path.write_text("multigrid: 3 levels\n")

    def freefem() -> None:
        time.sleep(0.2)  # the assembly: a heartbeat or more before the first step
        with open(path, "a") as f:
            f.write("newton 1 |R| 0.0013 alpha 1\n")
            f.flush()
            time.sleep(0.2)
            f.write("newton 2 |R| 5e-08 alpha 1\nnewton 3 |R| 2.7e-15 alpha 1\n")

    with watching(path, os.getpid(), "[6/6] n=64", said.append, EAGER):
        writer = threading.Thread(target=freefem)
        writer.start()
        writer.join()
    steps = [line for line in said if line.split(": ", 1)[1].startswith("newton ")]
    assert [line.split(": ", 1)[1].split(" |")[0] for line in steps] == ["newton 1", "newton 2", "newton 3"]
    assert all(line.startswith("[6/6] n=64 running ") for line in said)
    assert "FreeFEM CPU" in steps[0] and "GiB resident" in steps[0]
    assert any("still working, before the first Newton step" in line for line in said)
    assert any("still working, after newton 1" in line for line in said)


def test_a_short_wait_says_nothing(tmp_path):
    path, said = tmp_path / "stdout.txt", []
    path.write_text("newton 1 |R| 0.0013\nnewton 2 |R| 5e-08\n")
    with watching(path, os.getpid(), "[1/3] n=2", said.append, Pace(after_s=60.0, poll_s=0.01)):
        time.sleep(0.1)
    assert said == []


def test_a_chain_says_its_levels_newton_steps_before_their_done_line(tmp_path, monkeypatch):
    """On the real solver: each level's steps as FreeFEM printed them (3D n = 2 and 8 of the
    paper's block), then its done line."""
    monkeypatch.setattr(engine, "watching", functools.partial(watching, pace=EAGER))
    scene = load_scene(CASES / "paper3d.toml", ['scene.name="progress"'])
    layout = Layout(results=tmp_path)
    said: list[str] = []
    outcomes = run_levels(scene, InlineMeshes(scene, (2, 8), layout), layout, progress=said.append)
    assert all(o.ok for o in outcomes.values())
    for count, n in enumerate((2, 8), start=1):
        label = f"[{count}/2] n={n}"
        mine = [line for line in said if line.startswith(label)]
        its = outcomes[n].record.newton_iterations
        steps = [line for line in mine if ": newton " in line]
        assert [s.split(": newton ")[1].split(" ")[0] for s in steps] == [str(k) for k in range(1, its + 1)], mine
        assert mine[-1].startswith(f"{label} done in ")
    # Said as each step ended, not all at once when FreeFEM exits: newton.idp flushes each step's
    # line, which FreeFEM's endl leaves in the buffer. n = 8's steps take ~0.3 s of CPU each (n = 4's
    # ~0.05 s on an idle machine: all five printed the same tenth of a second there).
    cpu = [line.split("FreeFEM CPU ")[1].split(" s,")[0] for line in said
           if line.startswith("[2/2] n=8") and ": newton " in line]
    assert len(set(cpu)) > 1, cpu
