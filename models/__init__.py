"""Shipped weights (installed as ``coster_sumo.models``); see the model cards beside them."""
