"""Explorations of a design space on the independent closed-loop benchmark (issue 19): position-loop
pole specifications and the robust pole choice (``python -m bench.sweeps.control_specs``)."""
