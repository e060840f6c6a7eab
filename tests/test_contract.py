"""The integers shared by Python and FreeFEM come from one table (harness/core/contract.py)."""

from harness.core.contract import ExitCode, Failure, ROLE_LABELS, contract_idp, contract_path
from harness.core.freefem import EXIT_REASONS


def test_committed_contract_idp_is_generated_from_the_table():
    # Regenerate with `python -m harness.core.contract` after editing harness/core/contract.py.
    assert contract_path().read_text() == contract_idp()


def test_every_freefem_exit_code_has_one_failure_and_every_script_code_a_reason():
    codes = [f.code for f in Failure if f.code is not None]
    assert len(codes) == len(set(codes))
    for failure in Failure:
        if failure.code is not None:
            assert Failure.from_code(failure.code) is failure
            assert EXIT_REASONS[failure.code].startswith(failure.text)
    assert Failure.from_code(99) is Failure.OTHER


def test_labels_and_exit_codes_are_distinct():
    assert len(set(ROLE_LABELS.values())) == len(ROLE_LABELS)
    assert len({int(c) for c in ExitCode}) == len(ExitCode)
