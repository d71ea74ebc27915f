"""`python -m amfe ...` is the `amfe` command."""
import sys

from amfe.cli import entry

sys.exit(entry())
