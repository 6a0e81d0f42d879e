"""Subcommands of ``coster-sumo``: each module here has ``register(cli)`` (see coster_sumo.cli.command_line)."""
