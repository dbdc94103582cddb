"""Sparse identification (SINDy, weak SINDy, output-error refinement) of the plant."""
