"""Reproducers of fixed bugs: each shows the failure on the code before its fix and its absence after
(run from the repository root: ``python -m bench.repro.param_service``; results in
``bench/results/repro_*``, the causes in ``docs/findings/``)."""
