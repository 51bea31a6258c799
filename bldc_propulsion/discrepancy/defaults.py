"""The discrepancy workflow's decision thresholds (see workflow.py), in a module that imports
nothing: the `discrepancy` command's options default to them, and its --help must not pay
for numpy and scipy."""

ALPHA = 0.01  #: significance level of the held-out randomisation test
MIN_EFFECT = 0.10  #: least fractional held-out MSE reduction (beyond the null correction)
