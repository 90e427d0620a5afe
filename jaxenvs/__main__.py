import sys

from jaxenvs.cli import entry

sys.exit(entry())
