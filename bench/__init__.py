"""aeropend's benchmarks, run from the repository root as modules: ``python -m bench.bench_sim``.

``bench_*.py`` are the benchmarks (what each result file in ``results/`` is and the command that
makes it: ``results/INDEX.md``), ``repro/`` the reproducers of fixed bugs, ``sweeps/`` the
explorations of a design space, ``fixtures/`` what benchmarks and tests share (the independent
truth plant, the real-rig cases, minimal rigs, the batch closed loop), ``backends/`` the issue-37
study of simulator backends. The tests import ``bench.fixtures`` the same way (pytest's
``pythonpath`` puts the repository root on ``sys.path``).
"""
