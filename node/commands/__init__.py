"""Sub-commands of the ``ordervib`` console command, one module each.

Each module defines ``NAME`` (the sub-command), ``HELP`` (one line),
``add_arguments(parser)`` and ``run(args) -> int``. Register a new module in
``node.cli.COMMAND_MODULES``.
"""
