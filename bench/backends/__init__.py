"""Study prototype of issue 37 (compiled simulator backends); not product code.

``components`` writes the plant's physics once in the array-namespace style of issue 35 and
composes the rhs from a rig's effect switches; ``nb``, ``jx`` and ``cas`` compile that same rhs with
numba, JAX and CasADi; ``study`` holds the rig, inputs and LSODA reference shared with
``bench/bench_sim_backends.py``. Findings: ``docs/findings/simulator_backends.md``.
"""
