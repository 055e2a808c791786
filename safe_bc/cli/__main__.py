"""``python -m safe_bc.cli``: the ``safe-bc`` command."""

from safe_bc.cli.commands import main

main()
