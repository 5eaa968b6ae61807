"""The command line (typer) and what every command shares: its request model
(:mod:`.requests`), one :func:`~motionweb.flows.commands.cli.run_command` and the errors it
reports in one line (:mod:`.reported`) (design §10, the command core)."""
