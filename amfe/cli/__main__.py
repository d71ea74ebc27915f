"""`python -m amfe.cli ...` is the `amfe` command."""
import sys

from amfe.cli import entry

sys.exit(entry())
