"""`python -m zensim` is the `zensim` command."""

import sys

from zensim.cli import main

sys.exit(main())
