"""The nominal dataset (clips of traffic, one scene per file) and small synthetic scenes built in code."""
