"""The generation pipeline of ``coster-sumo run``.

The nominal scenario and its targets, the run itself, its outputs and its pictures.
"""
