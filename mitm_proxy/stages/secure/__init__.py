"""The secure stage: which readings feed the estimator, how it is stepped, what its output replaces."""
