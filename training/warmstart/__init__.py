"""Training and evaluation of the learned warm start (torch is imported only for training).

* ``data``: dataset records → canonical training arrays;
* ``train``: the network, ``slew train`` (config, checkpoints, log, loss plot, export);
* ``evaluate``: ``slew evaluate`` (learned vs eigenaxis, nearest-neighbour and random guesses).

Inference lives in ``solvers.warmstart`` (numpy).
"""
