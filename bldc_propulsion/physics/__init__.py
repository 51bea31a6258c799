"""The bench physics, in one place: the plant's equations and constants, the physics CONFIG, a
physics model as a model file and as a stream, the estimator's fallback, and the fits of the
constants to recordings (see docs/architecture.md, "physics/").

Below core/ in the layer order (scripts/imports.py): it imports only the shared modules, and the
simulator, the estimator, training and the discrepancy workflow import it. This file imports
nothing, so that a node that needs the plant does not load the fits (scipy) with it.
"""
