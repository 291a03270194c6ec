"""``python -m bifid`` runs the ``bifid`` command."""

from bifid.cli import main

main()
