"""The command line (SPEC C10): ``main`` assembles the subcommands in ``commands/``."""
