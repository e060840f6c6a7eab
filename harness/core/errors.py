"""Exceptions for expected failures: the CLI turns each into one `error:` line."""

from harness.core.contract import Failure


class HarnessError(Exception):
    """An expected failure whose message is one line a user can act on."""


class SceneError(HarnessError, ValueError):
    """The case file or an override is malformed or non-physical."""


class MeshError(HarnessError):
    """A generated mesh fails a check FreeFEM relies on."""


class RunError(HarnessError):
    """A FreeFEM run failed, timed out or did not converge; `failure` says which."""

    def __init__(self, message: str, failure: Failure = Failure.OTHER) -> None:
        super().__init__(message)
        self.failure = failure


class FieldsError(HarnessError):
    """A solution file is missing or lacks a field."""


class EnvironmentFault(HarnessError):
    """The machine, not the input: permissions, a full disk, a missing tool, too little memory."""


class StudyBusy(HarnessError):
    """Another live study is writing the same results directory."""


class VerdictError(HarnessError):
    """Everything ran, but a verdict failed: a physical check, a slope outside the band."""


class PeerMissing(EnvironmentFault):
    """GetFEM (Debian's python3-getfem) is not installed: only `crosscheck` needs it."""


class Disagreement(VerdictError):
    """FreeFEM and the GetFEM peer differ by more than the cross-check's tolerance."""
