"""Offline training: network maths (network.py), Levenberg-Marquardt (lm.py) and the workflow."""
