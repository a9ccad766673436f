"""`python -m taichi_mpm ...` is the `taichi-mpm` command."""
import sys

from .cli import main

sys.exit(main())
