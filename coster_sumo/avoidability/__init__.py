"""Step 8 of docs/method.md: could the target have escaped a generated collision, and each variant's label.

:mod:`.search` searches the escapes, :mod:`.evasion` holds the manoeuvres and vehicle limits, :mod:`.proof`
proves them in SUMO, :mod:`.labels` labels the kept variants and records what a planner did. Keeping
the avoidable variants draws again, so it lives a floor up: :func:`coster_sumo.method.generation.label_and_keep`.
"""
