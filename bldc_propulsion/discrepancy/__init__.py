"""Find where a model and measurements disagree, name the missing physical effect, add it.

``residuals`` (windows, whiteness, cross-correlation, conditions) -> ``effects`` (one candidate
feature per effect of the contract) -> ``scoring`` (held-out time blocks, significance) ->
``workflow`` (steps 1-5 and the loop) -> ``command`` (the `discrepancy` subcommand).
"""
