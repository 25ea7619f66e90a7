import sys

from .cli import main

if __name__ == "__main__":  # guard: Dask worker processes re-import __main__
    sys.exit(main())
