"""The sim-to-real gap diagnosis: effects, where, which, drift, report, synthetic checks."""
