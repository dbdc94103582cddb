"""Experiment design (issue 63)."""
