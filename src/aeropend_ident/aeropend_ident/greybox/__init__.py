"""Grey-box fitting of the physical model parameters, the baseline report, static estimators."""
