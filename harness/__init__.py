"""Verification harness: case file -> mesh -> FreeFEM run -> fields -> norms -> study -> report.

The sub-packages are layers in the order the data flows; a module imports only from its own
layer and the layers before it (tests/test_layers.py):

    core -> scene -> mesh -> run -> measure -> study -> report -> studies, cli

Each layer's `__init__` says what it holds.
"""

# The layer folders, bottom to top: a module may import from its own and the earlier ones.
LAYERS = ("core", "scene", "mesh", "run", "measure", "study", "report", "studies")
