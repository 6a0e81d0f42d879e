"""The regional traffic prior (docs/method.md step 2).

- :mod:`coster_sumo.prior.bins`: discretisation of agent attributes (value <-> class <-> bin centre);
- :mod:`coster_sumo.prior.features`: region tokens (map part and observed-agent part) and targets;
- :mod:`coster_sumo.prior.model`: :class:`PriorConfig` and the :class:`TrafficPrior` module;
- :mod:`coster_sumo.prior.infer`: loading checkpoints and batched prediction over a scene;
- :mod:`coster_sumo.prior.data`, :mod:`coster_sumo.prior.train`, :mod:`coster_sumo.prior.evaluate`,
  :mod:`coster_sumo.prior.baselines`: training and evaluation.

Importing this package does not import torch; the model modules do.
"""
