"""The project's SUMO scenarios (installed as ``coster_sumo.networks``); ``build.py`` regenerates them."""
