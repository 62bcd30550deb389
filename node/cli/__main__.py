"""``python -m node.cli``: the ``ordervib`` command."""

from node.cli import console

console()
