"""Find where a model and measurements disagree, name the missing physical effect, add it.

One loop, two model kinds:

- ``workflow`` (steps 1-5, the loop) talks to a model kind through the ``base.ModelKind``
  protocol (start, candidates, score, add, heldout, keep, finish): ``network`` (a trained
  network, ``--model``) and ``physics_kind`` (the bench physics, ``--physics``; the model and
  its CONFIG, calibration and fit flags are the package's ``physics/``, the effects' scores and
  strength fits on it ``physics`` here);
- ``residuals`` (windows, whiteness, cross-correlation, conditions), ``effects`` (one candidate
  feature per effect of the contract), ``scoring`` (held-out time blocks, significance),
  ``identify`` (the identification rules: dynamics, start level, heating, which one changed),
  ``acceptance`` (held-out evidence decides what is kept);
- ``results`` (evidence, rounds and the result as dataclasses with ``as_json()``, the summary
  lines, the report), and ``commands/discrepancy.py`` the `discrepancy` subcommand.
"""
