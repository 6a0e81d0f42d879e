"""The data every stage shares: scenes, plans, collision snapshots, specs and run results (plain types, no SUMO)."""
