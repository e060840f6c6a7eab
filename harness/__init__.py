"""Verification harness: case file -> mesh -> FreeFEM run -> fields -> norms -> study -> report."""
