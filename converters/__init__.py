"""Readers and writers at the boundary: WOMD TFRecords, ScenarioNet pickles, SUMO networks."""
