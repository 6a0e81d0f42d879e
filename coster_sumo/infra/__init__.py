"""Infrastructure without domain knowledge.

Atomic writes, output folders, child processes, progress bars, devices, model weights, finding SUMO.
"""
