"""Exceptions for expected failures: the CLI turns each into one `error:` line."""


class HarnessError(Exception):
    """An expected failure whose message is one line a user can act on."""


class SceneError(HarnessError, ValueError):
    """The case file or an override is malformed or non-physical."""


class MeshError(HarnessError):
    """A generated mesh fails a check FreeFEM relies on."""


class RunError(HarnessError):
    """A FreeFEM run failed, timed out or did not converge."""


class FieldsError(HarnessError):
    """A solution file is missing or lacks a field."""
