import sys

if __name__ == "__main__":  # guard: Dask worker processes re-import __main__
    try:
        from .cli import main
    except KeyboardInterrupt:  # a Ctrl-C while Python is still importing: no traceback
        sys.stderr.write("graphkit: interrupted\n")
        sys.exit(130)
    sys.exit(main())
