"""The COSTER method, one module per step of docs/method.md (the models are :mod:`coster_sumo.prior`
and :mod:`coster_sumo.rollout`; the regions they read are :mod:`coster_sumo.prior.regions`):

- :mod:`coster_sumo.method.collision_time`: step 3, the search window, the rules, the entropy curve;
- :mod:`coster_sumo.method.snapshot`: step 4, the adversary's placement at t_col (and the random
  baseline), with :mod:`coster_sumo.method.plausible` for a real vehicle's size and speed;
- :mod:`coster_sumo.method.filters`: step 6, the candidates kept (no contact before t_col);
- :mod:`coster_sumo.method.generation`: the steps together, one loop of draws for every command.

Importing this package does not import torch; the prior and the CVAE load when a draw needs them.
"""
