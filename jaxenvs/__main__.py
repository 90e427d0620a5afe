import sys

from jaxenvs.cli import main

sys.exit(main())
