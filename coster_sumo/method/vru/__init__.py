"""Vulnerable road users as adversaries (docs/method.md, "Pedestrian and cyclist adversaries"):
the class limits (:mod:`.classes`), where a class may be (:mod:`.areas`), the class's collision
snapshot (:mod:`.snapshot`) and its time-reversed rollout with the class's kinematics (:mod:`.rollout`)."""
