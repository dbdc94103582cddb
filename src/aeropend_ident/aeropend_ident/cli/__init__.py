"""Command-line front ends: argument parsing and ``main`` only."""
