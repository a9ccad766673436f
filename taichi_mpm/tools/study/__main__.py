"""`python -m taichi_mpm.tools.study --case CASE.json --result OUT.json`: the process of one study case (case.py)."""
import sys

from .case import main

sys.exit(main())
