"""The command line: every expected failure is one `error:` line and its exit code (2 bad
input, 3 a failed run, 4 the environment, 1 a slope outside the band: harness/core/faults.py),
and a failed run or study leaves earlier results untouched.
FreeFEM itself runs, on the stand-in solver of tests/data/stub_freefem."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import pytest

from harness.core import freefem
from harness.cli import main
from harness.run.record import read_run_json


def run(capsys, layout, *argv: str) -> tuple[int, list[str], str]:
    code = main([*argv, "--results", str(layout.results), "--freefem", str(layout.freefem)])
    captured = capsys.readouterr()
    return code, captured.err.strip().splitlines(), captured.out


def solve(capsys, layout, case: Path, *extra: str) -> tuple[int, list[str], str]:
    return run(capsys, layout, "solve", str(case), "--n", "4", *extra)


def one_error_line(err: list[str], *words: str) -> str:
    assert len(err) == 1 and err[0].startswith("error: "), err
    assert all(word in err[0] for word in words), err
    return err[0]


def test_a_missing_case_file(capsys, stub_layout, tmp_path):
    code, err, _ = solve(capsys, stub_layout, tmp_path / "absent.toml")
    assert code == 2
    one_error_line(err, "case file not found", "absent.toml")


def test_a_malformed_case_file(capsys, stub_layout, tmp_path):
    case = tmp_path / "case.toml"
    case.write_text("[scene]\nname = \n")
    code, err, _ = solve(capsys, stub_layout, case)
    assert code == 2
    one_error_line(err, "malformed case file", "case.toml")


def test_an_unknown_material_fails_before_anything_is_made(capsys, stub_layout, paper_case):
    code, err, _ = solve(capsys, stub_layout, paper_case, "--set", "scene.material=Unobtainium")
    assert code == 2
    one_error_line(err, "unknown material 'Unobtainium'", "Unobtainium.idp")
    assert not stub_layout.results.exists()


@pytest.mark.parametrize("study", [["solve", "--n", "2"], ["convergence", "--levels", "2,4,8"], ["cost"]])
def test_a_missing_freefem_scripts_directory_is_named(capsys, tmp_path, paper_case, study):
    # It said "unknown material 'BaTiO3'" (and cost ignored --freefem altogether).
    missing = tmp_path / "nonexistent"
    code = main([study[0], str(paper_case), *study[1:], "--results", str(tmp_path / "results"),
                 "--freefem", str(missing)])
    assert code == 2
    one_error_line(capsys.readouterr().err.strip().splitlines(),
                   f"--freefem {missing}: the FreeFEM scripts directory does not exist")
    assert not (tmp_path / "results").exists()


def test_a_freefem_directory_without_the_scheme_is_named(capsys, tmp_path, paper_case):
    code = main(["solve", str(paper_case), "--n", "2", "--results", str(tmp_path / "results"),
                 "--freefem", str(tmp_path)])
    assert code == 2
    one_error_line(capsys.readouterr().err.strip().splitlines(), f"--freefem {tmp_path}: not a FreeFEM scripts "
                   "directory (no scheme.idp)")


def test_a_bad_set_key(capsys, stub_layout, paper_case):
    # (contact.mu exists since Coulomb friction: a static coefficient does not.)
    code, err, _ = solve(capsys, stub_layout, paper_case, "--set", "contact.mu_static=0.3")
    assert code == 2
    one_error_line(err, "contact.mu_static")


@pytest.mark.parametrize("override", ["electric_contact.k_e=inf", "thermal_contact.theta_f=inf",
                                      "loads.traction_y=inf", "contact.c_nu=inf"])
def test_inf_is_bad_input_before_anything_is_made(capsys, stub_layout, paper_case, override):
    code, err, _ = solve(capsys, stub_layout, paper_case, "--set", override)
    assert code == 2
    one_error_line(err, override.partition("=")[0], "finite")
    assert not stub_layout.results.exists()


@pytest.mark.parametrize("address", ["notaurl", "tcp://localhost", "http://localhost:8786", "", " ", "tcp://:8786",
                                     "tcp://localhost:0", "tcp://localhost:99999"])
@pytest.mark.parametrize("study", ["stress", "scenes", "branches"])
def test_a_bad_scheduler_address_is_one_line_before_anything_runs(capsys, tmp_path, study, address):
    # It was a ValueError traceback from Dask (exit 1), and "" silently ran in this process.
    with pytest.raises(SystemExit) as info:
        main([study, "--scheduler", address, "--results", str(tmp_path / "results")])
    assert info.value.code == 2
    one_error_line(capsys.readouterr().err.strip().splitlines(), "--scheduler", repr(address),
                   "SCHEME://HOST:PORT")
    assert not (tmp_path / "results").exists()


def test_an_empty_cluster_is_refused_too(capsys, tmp_path):
    with pytest.raises(SystemExit) as info:
        main(["stress", "--cluster", "", "--results", str(tmp_path / "results")])
    assert info.value.code == 2
    one_error_line(capsys.readouterr().err.strip().splitlines(), "--cluster", "local:N")


@pytest.mark.parametrize("address", ["tcp://127.0.0.1:8786", "tls://scheduler.example:8786", "tcp://[::1]:8786"])
def test_a_scheduler_address_with_scheme_host_and_port_is_taken(address):
    from harness.study.executor import scheduler_address

    assert scheduler_address(address) == address


@pytest.mark.parametrize("argv", [["convergence", "x.toml", "--levels", "2,x"], ["solve", "x.toml"], ["nope"]])
def test_bad_command_lines_are_one_line_too(capsys, argv):
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    one_error_line(capsys.readouterr().err.strip().splitlines())


def test_freefem_missing_from_the_path(capsys, stub_layout, paper_case, monkeypatch):
    monkeypatch.setattr(freefem, "BINARY", "FreeFem++-not-installed")
    freefem.freefem_version.cache_clear()
    try:
        code, err, _ = solve(capsys, stub_layout, paper_case)
    finally:
        freefem.freefem_version.cache_clear()
    assert code == 4  # ENVIRONMENT: a missing tool (exit-code table, issue 14)
    one_error_line(err, "FreeFem++-not-installed not found")


def test_solve_passes_the_scene_to_freefem_and_summarises_run_json(capsys, stub_layout, paper_case):
    code, err, out = solve(capsys, stub_layout, paper_case, "--set", "loads.traction_y=-12.5")
    assert code == 0 and err == []
    assert "paper n=4: converged in 3 Newton iterations" in out
    record = read_run_json(stub_layout.level_dir("paper", 4))
    # The stub echoes -loads.traction_y and -electric_contact.L (inf goes as 1e300).
    assert record.contact_force == -12.5 and record.active_measure == 1e300
    assert record.wall_s > 0
    main_edp = (stub_layout.level_dir("paper", 4) / "main.edp").read_text().splitlines()
    # One macro per effect of the scene, then the material and the scheme.
    assert "macro effElectricContact 1 //" in main_edp
    assert main_edp[-1].endswith('stub_freefem/scheme.idp"')


@pytest.mark.parametrize(
    "material, words",
    [
        ("Diverge", ["Newton diverged: no progress (a cycle, or 5 steps without passing the line search), also from the pressed restart", "stub reason", "n4.failed/stdout.txt"]),
        ("Broken", ["FreeFEM compile error", "Broken.idp"]),
        ("Silent", ["FreeFEM wrote no readable run.json"]),
        ("Unconverged", ["not converged: stub reason"]),
    ],
)
def test_a_failed_run_is_one_line_and_keeps_the_good_result(capsys, stub_layout, paper_case, material, words):
    assert solve(capsys, stub_layout, paper_case)[0] == 0
    good = stub_layout.level_dir("paper", 4)
    before = {p.name: p.read_bytes() for p in good.iterdir()}
    code, err, _ = solve(capsys, stub_layout, paper_case, "--set", f"scene.material={material}")
    assert code == 3  # RUN: a failed FreeFEM run (exit-code table, issue 14)
    one_error_line(err, "paper n=4: ", *words)
    assert {p.name: p.read_bytes() for p in good.iterdir()} == before
    failed = stub_layout.failed_dir("paper", 4)
    assert (failed / "stdout.txt").is_file() and (failed / "stderr.txt").is_file()
    assert not list(good.parent.glob(".tmp-*"))


def test_a_hung_run_is_killed_with_its_children_at_the_timeout(capsys, stub_layout, paper_case):
    start = time.monotonic()
    code, err, _ = solve(capsys, stub_layout, paper_case, "--set", "scene.material=Hang", "--set", "run.timeout_s=2")
    assert code == 3 and time.monotonic() - start < 30  # the child would sleep 60 s
    one_error_line(err, "timed out after 2 s")
    child = int((stub_layout.failed_dir("paper", 4) / "child.pid").read_text())
    deadline = time.monotonic() + 10  # the orphaned child is reaped by init, not instantly
    while time.monotonic() < deadline and alive(child):
        time.sleep(0.1)
    assert not alive(child)


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    stat = Path(f"/proc/{pid}/stat")
    return not (stat.exists() and stat.read_text().split()[2] == "Z")  # a zombie is dead


def convergence(capsys, layout, case: Path, *extra: str) -> tuple[int, list[str], str]:
    return run(capsys, layout, "convergence", str(case), "--levels", "2,4,8", "--jobs", "2", *extra)


def test_a_study_with_a_failed_level_leaves_the_previous_report(capsys, stub_layout, paper_case):
    assert convergence(capsys, stub_layout, paper_case)[0] == 0
    report = stub_layout.case_dir("paper")
    before = {name: (report / name).read_bytes() for name in ("convergence.csv", "summary.json", "convergence.png")}
    code, err, _ = convergence(capsys, stub_layout, paper_case, "--set", "scene.material=Diverge")
    assert code == 3  # RUN
    one_error_line(err[-1:], "Newton diverged", "(+2 more failed levels)")
    assert all(line.startswith("[") and "FAILED" in line for line in err[:-1])
    assert {name: (report / name).read_bytes() for name in before} == before


def test_a_slope_outside_the_band_exits_1_saying_why(capsys, stub_layout, paper_case):
    code, err, out = convergence(capsys, stub_layout, paper_case, "--set", "study.slope_band=[1.5, 2.0]")
    assert code == 1
    one_error_line(err[-1:], "total slope", "outside the band [1.5, 2.0]", "paper.toml")
    assert "err_total" in out  # the table is printed all the same
    summary = json.loads((stub_layout.case_dir("paper") / "summary.json").read_text())
    assert summary["verdict"] == "fail"


def test_an_unknown_coarse_space_for_make_scale_fails_before_any_run(capsys, tmp_path):
    code = main(["scale", "--mpi-levels", "4", "--mpi-3d-levels", "", "--stress-levels", "2",
                 "--clusters", "", "--coarse-spaces", "none,bogus", "--results", str(tmp_path)])
    assert code == 2
    one_error_line(capsys.readouterr().err.strip().splitlines(), "run.coarse_space = 'bogus'")
    assert not (tmp_path / "scale").exists()
