"""The time-reversed CVAE rollout (docs/method.md steps 5-6) and its baselines.

- :mod:`coster_sumo.rollout.model`: :class:`~coster_sumo.rollout.model.RolloutConfig` and the
  :class:`~coster_sumo.rollout.model.RolloutCVAE` module (map encoder, per-step latents, dynamic
  surrounding attention);
- :mod:`coster_sumo.rollout.data`: everything in the reconstructed vehicle's frame at t_rev: map
  chunks, neighbours per step, ground-truth reverse segments, batching (numpy; torch only when
  tensors are made);
- :mod:`coster_sumo.rollout.checkpoint`: saving and loading weights (``weights_only=True``);
- :mod:`coster_sumo.rollout.train`, :mod:`coster_sumo.rollout.evaluate`: training and evaluation;
- :mod:`coster_sumo.rollout.baselines`: constant velocity and constant lane, backwards;
- :mod:`coster_sumo.rollout.vocab`: the motion vocabulary (k-disks over 0.5 s transitions) and the
  projection of a trajectory onto it, chained backwards from the collision snapshot;
- :mod:`coster_sumo.rollout.sample`: the public API of the injection pipeline:
  :func:`~coster_sumo.rollout.sample.sample_trajectories` (oversampling in one batched pass) and
  :func:`~coster_sumo.rollout.sample.select_representatives` (K-means, vocabulary, rejection).

Importing this package does not import torch; the model modules do.
"""
