"""One module per ``jaxenvs`` subcommand (``<name>_cmd.py``): HELP, add_arguments, run."""
