"""RunRecord against what FreeFEM writes: every key of run.json that freefem/output.idp (and
the reference errors it includes) writes is declared, and so is every check."""

from __future__ import annotations

import re

import pytest

from harness.core.errors import FieldsError
from harness.core.layout import REPO
from harness.run.record import CHECK_KEYS, HARNESS_KEYS, KEYS, RunRecord

FREEFEM = REPO / "freefem"
# A top-level key: `jsonField(f, "name", ...)`, `perFieldJson(f, "name", ...)` (json.idp) or a
# line `f << "  \"name\": ...` (two spaces); a check: `f << "    \"name\": ...` (four
# spaces, inside "checks").
TOP = re.compile(r'(?:jsonField|perFieldJson)\(f, "(\w+)",|f << "  \\"(\w+)\\":')
CHECK = re.compile(r'f << "    \\"(\w+)\\":')
RANGE = re.compile(r'jsonField\(f, "(min|max)_" \+ name')


def written(path) -> tuple[set[str], set[str]]:
    text = path.read_text()
    top = {a or b for a, b in TOP.findall(text)}
    return top, set(CHECK.findall(text))


def test_every_key_output_idp_writes_is_declared():
    top, checks = written(FREEFEM / "output.idp")
    history, _ = written(FREEFEM / "json.idp")  # the Newton run and the ranks' figures, output.idp's macros
    top |= history
    passed, _ = written(FREEFEM / "ranks_record.idp")  # the sequential pass's own keys, output.idp's macro
    top |= passed
    reference, _ = written(FREEFEM / "reference_error.idp")
    estimator, _ = written(FREEFEM / "estimator.idp")
    reactions, _ = written(FREEFEM / "reactions.idp")
    reference |= estimator | reactions  # each writes its keys through a macro output.idp calls
    goals, _ = written(FREEFEM / "goals.idp")  # the goal estimates, through goalJson, which output.idp calls
    assert {"goal_estimates", "goal_dofs", "goal_s"} <= goals
    reference |= goals
    assert {"n", "converged", "checks", "max_abs_u", "mms_errors"} <= top  # the parse finds them
    assert {"reference_errors", "reference_s"} <= reference
    assert {"estimator", "estimator_norms"} <= estimator
    assert {"reactions"} <= reactions
    assert (top | reference) - KEYS == set()
    assert checks == CHECK_KEYS
    # The per-field ranges ("min_" + name) of the scalar fields the harness knows.
    assert RANGE.search((FREEFEM / "output.idp").read_text())
    assert {"min_phi", "max_phi", "min_theta", "max_theta"} <= KEYS
    # Nothing declared that nobody writes.
    ranges = {"min_phi", "max_phi", "min_theta", "max_theta"}
    assert KEYS - (top | reference | ranges | set(HARNESS_KEYS)) == set()


def test_an_undeclared_or_missing_key_is_an_error():
    good = {"n": 2, "converged": True, "reason": "converged", "newton_iterations": 3, "dofs": 90,
            "fields": ["u"]}
    assert RunRecord.from_json(good).newton_iterations == 3
    with pytest.raises(FieldsError, match="undeclared key 'newton_its'"):
        RunRecord.from_json({**good, "newton_its": 3})
    with pytest.raises(FieldsError, match="did not write 'dofs'"):
        RunRecord.from_json({k: v for k, v in good.items() if k != "dofs"})
    with pytest.raises(FieldsError, match="undeclared check"):
        RunRecord.from_json({**good, "checks": {"force_balance": 0.0}})
    # A failed run may stop early: only its declared keys are checked.
    assert RunRecord.from_json({"converged": False, "reason": "nan"}).reason == "nan"


def test_to_json_round_trips_and_leaves_absent_keys_out():
    record = RunRecord(n=4, converged=True, wall_s=1.5)
    assert record.to_json() == {"n": 4, "converged": True, "wall_s": 1.5}
    assert RunRecord.from_json({**record.to_json(), "reason": "", "newton_iterations": 1, "dofs": 1,
                                "fields": []}).wall_s == 1.5


def test_a_run_json_written_before_the_rename_still_reads():
    """`active_length` (an area in 3D) is now `active_measure`; a cached run.json from before
    the rename reads with its value under the new name."""
    old = {"n": 2, "converged": True, "reason": "converged", "newton_iterations": 3, "dofs": 90,
           "fields": ["u"], "active_length": 2.0}
    assert RunRecord.from_json(old).active_measure == 2.0
