"""training: datasets, the warm-start network, RL scripts and the ``slew`` command line.

Importing this package does not import torch; only the training entry points do.
"""
