"""The ``coster-sumo`` command: the client, the command line and the server.

The commands themselves are in :mod:`coster_sumo.cli.commands`.
"""
